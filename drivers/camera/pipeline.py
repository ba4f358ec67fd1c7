"""From an image to `Detections`: detector -> descriptor -> undistortion -> depth.

The descriptor is computed on the image as captured (the box pixels), then the boxes are
undistorted (corners through the calibration's distortion model) so that the boxes leaving
the driver are ideal-pinhole boxes for `CameraModel.K`, as the frustum separation assumes.
Depth comes from the model when it has a depth output, else from the ground plane.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from mmatch.drivers.camera.calibration import Calibration
from mmatch.drivers.camera.decode import Decoded
from mmatch.drivers.camera.depth import DepthConfig, GroundPlane, ground_plane_depth, model_depth_sigma
from mmatch.drivers.camera.descriptor import hsv_descriptor
from mmatch.types import DESCRIPTOR_DIM, Detections

log = logging.getLogger(__name__)

#: Per-box pixel budget of the descriptor in the driver (see DetectionStage).
DEFAULT_DESCRIPTOR_MAX_PIXELS = 4096


@dataclass
class CameraDetections(Detections):
    """`Detections` plus what the camera driver knows beyond the shared contract.

    depth_sigma: float32 (M,) 1-sigma depth uncertainty, m; classes: int32 (M,) detector
    class ids; depth_source: "model" or "ground".
    """

    depth_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    classes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    depth_source: str = "ground"


def empty_camera_detections(stamp: float) -> CameraDetections:
    return CameraDetections(
        boxes=np.zeros((0, 6), np.float32),
        features=np.zeros((0, DESCRIPTOR_DIM), np.float32),
        stamp=stamp,
    )


@dataclass
class FrameCounters:
    """Frames seen, used and skipped (by reason)."""

    frames: int = 0
    detections: int = 0
    skipped_type: int = 0
    skipped_size: int = 0

    def as_dict(self) -> dict[str, int]:
        return {
            "frames": self.frames,
            "detections": self.detections,
            "skipped_type": self.skipped_type,
            "skipped_size": self.skipped_size,
        }


def check_frame(image: object, image_size: tuple[int, int] | None) -> str | None:
    """Why a frame must be skipped ("type" or "size"), or None when it is a usable
    uint8 (H, W, 3) BGR image of the calibrated (width, height)."""
    if (
        not isinstance(image, np.ndarray)
        or image.dtype != np.uint8
        or image.ndim != 3
        or image.shape[2] != 3
    ):
        return "type"
    if image_size is not None and (image.shape[1], image.shape[0]) != tuple(image_size):
        return "size"
    return None


class DetectionStage:
    """Turns a BGR image into CameraDetections (boxes u1, v1, u2, v2, score, depth + descriptors).

    detect: callable image -> Decoded (boxes in image px), e.g. `OnnxDetector.detect`; for the
        OAK backend the device detects and `process_decoded` is called instead.
    calibration: intrinsics/distortion/image size; ground: the road plane for depth (None:
        from the calibration's [ground] table or its extrinsic and `radar_height`).
    descriptor_max_pixels: boxes with more pixels are histogrammed on a regular grid (every
        k-th row and column) of about this many pixels; None uses every pixel. The default 4096
        halves the descriptor time for 20 boxes (bench) for a bin error of at most ~0.015
        (painted vehicles; 0 on uniform boxes), below what two cameras' lighting differs by.
    """

    def __init__(
        self,
        detect,
        calibration: Calibration,
        ground: GroundPlane | None = None,
        radar_height: float | None = None,
        depth: DepthConfig | None = None,
        descriptor_max_pixels: int | None = DEFAULT_DESCRIPTOR_MAX_PIXELS,
    ) -> None:
        self._detect = detect
        self.calibration = calibration
        self.ground = ground or calibration.ground_plane(radar_height)
        self.depth_config = depth or DepthConfig()
        self.descriptor_max_pixels = descriptor_max_pixels
        self.counters = FrameCounters()

    def process(self, image: np.ndarray, stamp: float) -> CameraDetections | None:
        """Detections of one image, or None when the frame is skipped (wrong type/size; counted)."""
        self.counters.frames += 1
        why = check_frame(image, self.calibration.image_size)
        if why is not None:
            if why == "type":
                self.counters.skipped_type += 1
            else:
                self.counters.skipped_size += 1
            skipped = self.counters.skipped_type + self.counters.skipped_size
            shape = getattr(image, "shape", None)
            dtype = getattr(image, "dtype", type(image).__name__)
            # the first skip and then every 100th at WARNING (a camera that ignores the requested
            # resolution would otherwise fail silently), the rest at DEBUG
            level = logging.WARNING if skipped == 1 or skipped % 100 == 0 else logging.DEBUG
            log.log(
                level,
                "skipping frame at %.3f (%d skipped so far): wrong %s: got %s %s, expected uint8 "
                "(%d, %d, 3) as calibrated",
                stamp,
                skipped,
                why,
                shape,
                dtype,
                self.calibration.image_size[1],
                self.calibration.image_size[0],
            )
            return None
        return self.process_decoded(image, self._detect(image), stamp)

    def process_decoded(
        self, image: np.ndarray | None, dec: Decoded, stamp: float
    ) -> CameraDetections:
        """Descriptors, undistortion and depth for boxes already detected in `image` (image px)."""
        m = len(dec)
        self.counters.detections += m
        if m == 0:
            return empty_camera_detections(stamp)
        if image is not None:
            feats = hsv_descriptor(image, dec.boxes, self.descriptor_max_pixels)
        else:
            from mmatch.drivers.camera.descriptor import UNIFORM_DESCRIPTOR

            feats = np.tile(UNIFORM_DESCRIPTOR, (m, 1))
        und = self.calibration.undistort_boxes(dec.boxes[:, :4])
        if dec.depth is not None and np.isfinite(dec.depth).all():
            depth = dec.depth.astype(np.float32)
            sigma = model_depth_sigma(depth, self.depth_config)
            source = "model"
        elif self.ground is not None:
            depth, sigma = ground_plane_depth(
                und, self.calibration.K, self.ground, self.calibration.image_size, self.depth_config
            )
            source = "ground"
        else:
            # No road plane known: the size prior alone (vehicle height over box height).
            h = np.maximum(und[:, 3] - und[:, 1], 1.0)
            depth = (self.calibration.K[1, 1] * self.depth_config.vehicle_height / h).astype(
                np.float32
            )
            sigma = (depth * self.depth_config.size_prior_rel_sigma).astype(np.float32)
            source = "size"
        boxes = np.empty((m, 6), np.float32)
        boxes[:, :4] = und
        boxes[:, 4] = dec.scores
        boxes[:, 5] = depth
        return CameraDetections(
            boxes=boxes,
            features=feats,
            stamp=stamp,
            depth_sigma=sigma.astype(np.float32),
            classes=dec.classes.astype(np.int32),
            depth_source=source,
        )
