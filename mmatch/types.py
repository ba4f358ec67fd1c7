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
DESCRIPTOR_GROUPS = ((0, 16), (16, 24), (24, 32))     # the descriptor's H, S and V histograms
BOX_COLUMNS: tuple[str, ...] = ("u1", "v1", "u2", "v2", "score", "depth")


def empty_points() -> np.ndarray:
    """An empty (0, 5) float32 point array."""
    return np.zeros((0, 5), dtype=np.float32)


def normalised_descriptors(features: np.ndarray) -> np.ndarray:
    """float32 (M, 32) descriptors with each H, S and V group a distribution, as DESIGN.md
    defines them: negative bins 0, each group scaled to sum to 1 (a sender that counts pixels),
    a group without mass uniform (no colour measured, as the camera driver describes a box
    without pixels). Rows that are distributions already (within 1e-3) and rows with a
    non-finite value come back as they are."""
    f = np.array(features, np.float32).reshape(-1, DESCRIPTOR_DIM)
    finite = np.all(np.isfinite(f), axis=1)
    for lo, hi in DESCRIPTOR_GROUPS:
        g = np.clip(f[:, lo:hi], 0, None)
        mass = g.sum(axis=1)
        fix = finite & ((np.abs(mass - 1) > 1e-3) | np.any(f[:, lo:hi] < 0, axis=1))
        if fix.any():
            m = mass[fix, None]
            uniform = np.float32(1 / (hi - lo))
            f[fix, lo:hi] = np.where(m > 0, g[fix] / np.where(m > 0, m, 1), uniform)
    return f


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
