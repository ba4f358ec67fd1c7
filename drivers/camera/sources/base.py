"""The camera source interface (same shape as edge.sources.base.CameraSource, which the
vehicle loop uses; drivers cannot import edge, so edge adapts these by duck typing).

A source is a context manager whose close() is safe twice. `read(timeout)` returns the next
`Detections` (stamp = image capture time on the shared clock, s), None when nothing came
within `timeout` seconds or the frame was skipped (wrong size/type; counted), raises
`CameraUnavailable` (a DeviceError) when the device is gone and `EndOfStream` when a finite
source is exhausted. `ResilientCamera` wraps any source so that none of this ever reaches
the caller's radar loop.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Callable

import numpy as np

from mmatch.drivers.camera.pipeline import CameraDetections, DetectionStage
from mmatch.types import CameraModel, Detections


class CameraSource(abc.ABC):
    """A camera with its detector: boxes, depths and appearance descriptors per image."""

    #: backend name as used in configs ("opencv", "oak", "replay", "sim")
    name: str = ""
    #: True for finite sources that must not lose frames (replay)
    lossless: bool = False

    def open(self) -> None:  # noqa: B027 - optional hook
        """Acquire the device (may raise CameraUnavailable / ModelError)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice."""

    @property
    @abc.abstractmethod
    def camera(self) -> CameraModel:
        """Intrinsics (of the undistorted boxes), image size and T_cam_radar."""

    @abc.abstractmethod
    def read(self, timeout: float) -> Detections | None:
        """The next detections, or None after `timeout` s (or a skipped frame)."""

    def counters(self) -> dict[str, int]:
        """Frames, detections and skips by reason."""
        return {}

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ImageCameraBase(CameraSource):
    """A source of BGR images run through a `DetectionStage` (OpenCV devices, image replays).

    Subclasses implement `_grab(timeout) -> (image, stamp) | None`.
    """

    def __init__(self, stage: DetectionStage, clock: Callable[[], float] = time.time) -> None:
        self.stage = stage
        self.clock = clock

    @property
    def camera(self) -> CameraModel:
        return self.stage.calibration.camera_model()

    @abc.abstractmethod
    def _grab(self, timeout: float) -> tuple[object, float] | None:
        """One raw frame and its capture stamp (s), None when none came in time."""

    def read(self, timeout: float) -> CameraDetections | None:
        got = self._grab(timeout)
        if got is None:
            return None
        image, stamp = got
        return self.stage.process(image, stamp)

    def counters(self) -> dict[str, int]:
        return self.stage.counters.as_dict()


def as_float_stamp(value: object) -> float:
    """A stamp as float seconds (NaN when missing)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def empty_boxes() -> np.ndarray:
    return np.zeros((0, 6), np.float32)
