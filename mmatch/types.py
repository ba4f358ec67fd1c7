"""Core data types shared by every package (DESIGN.md "Conventions").

Point clouds are float32 arrays (N, 5) with columns x, y, z, doppler, snr in the radar
frame (x right, y forward, z up; metres; doppler m/s, positive = range increasing;
snr dB). Poses are float64 4x4 homogeneous matrices.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

POINT_COLUMNS: tuple[str, ...] = ("x", "y", "z", "doppler", "snr")
X, Y, Z, DOPPLER, SNR = range(5)
DESCRIPTOR_DIM = 32
BOX_COLUMNS: tuple[str, ...] = ("u1", "v1", "u2", "v2", "score", "depth")


def empty_points() -> np.ndarray:
    """An empty (0, 5) float32 point array."""
    return np.zeros((0, 5), dtype=np.float32)


@dataclass
class RadarFrame:
    """One radar frame in mmatch conventions.

    points: float32 (N, 5) x, y, z, doppler, snr (radar frame).
    stamp: capture time, s, on the shared clock (or the host clock if none).
    frame_number: device frame counter (-1 when unknown).
    host_time: host receive time, s (time.time()).
    device: free-form device timing fields (e.g. timeCpuCycles, subFrameNumber).
    """

    points: np.ndarray
    stamp: float = 0.0
    frame_number: int = -1
    host_time: float = 0.0
    device: dict = field(default_factory=dict)


@dataclass
class Detections:
    """Camera detections of one image.

    boxes: float32 (M, 6) u1, v1, u2, v2 (px), score (0-1), depth (m, camera to vehicle centre).
    features: float32 (M, 32) appearance descriptors (HSV histogram, DESIGN.md).
    stamp: capture time, s.
    """

    boxes: np.ndarray
    features: np.ndarray
    stamp: float = 0.0


@dataclass
class CameraModel:
    """Pinhole camera with its extrinsic to the radar.

    K: float64 (3, 3) intrinsics; image_size: (width, height) px;
    T_cam_radar: float64 (4, 4) mapping radar points into the OpenCV camera frame.
    """

    K: np.ndarray
    image_size: tuple[int, int]
    T_cam_radar: np.ndarray


@dataclass
class View:
    """Everything one vehicle contributes to a scene (one side of a scene file)."""

    points: np.ndarray
    boxes: np.ndarray
    features: np.ndarray
    camera: CameraModel
    stamp: float
    radar_height: float
    point_labels: np.ndarray | None = None
    box_ids: np.ndarray | None = None


@dataclass
class Scene:
    """An Ego/CAV frame pair with ground truth (`mmatch-scene/1`)."""

    ego: View
    cav: View
    gt_T_ego_cav: np.ndarray
    gt_pairs: np.ndarray
    meta: dict = field(default_factory=dict)
    name: str = ""
