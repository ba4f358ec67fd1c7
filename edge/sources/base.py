"""The two source interfaces. Each backend is a context manager whose close() is safe twice.

`read(timeout)` returns the next frame, None when nothing came within `timeout` seconds,
and raises `DeviceError` when the device is gone (the loop then closes, waits and reopens:
a replugged sensor comes back without a restart). `EndOfStream` means a finite source
(a replay) has nothing more.
"""

from __future__ import annotations

import abc
from collections.abc import Callable

import numpy as np

from mmatch.errors import MMatchError
from mmatch.types import CameraModel, Detections, RadarFrame


class EndOfStream(MMatchError):
    """A finite source (log, capture file) is exhausted."""


class _Source(abc.ABC):
    #: True for sources that must not lose frames (replay): the loop then blocks instead of dropping.
    lossless: bool = False

    def open(self) -> None:  # noqa: B027 - optional hook
        """Acquire the device (may raise DeviceError)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice."""

    def counters(self) -> dict[str, int]:
        """Backend counters (frames, bytes skipped, rejects by reason, ...)."""
        return {}

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RadarSource(_Source):
    """A radar: frames of float32 (N, 5) x, y, z, doppler, snr points in the radar frame."""

    #: set by the loop: receives raw bytes (UART) or raw frames (DCA1000) for the log
    raw_sink: Callable[[bytes], None] | None = None
    #: the log topic of the raw data
    raw_topic: str = "/raw/uart"

    @abc.abstractmethod
    def read(self, timeout: float) -> RadarFrame | None:
        """The next radar frame (stamp on the shared clock, s), or None after `timeout` s."""


class CameraSource(_Source):
    """A camera with its detector: boxes, depths and appearance descriptors per image."""

    @property
    @abc.abstractmethod
    def camera(self) -> CameraModel:
        """Intrinsics, image size and T_cam_radar."""

    @abc.abstractmethod
    def read(self, timeout: float) -> Detections | None:
        """The next detections (stamp = image capture time, s), or None after `timeout` s."""


def empty_detections(stamp: float = float("nan")) -> Detections:
    return Detections(boxes=np.zeros((0, 6), np.float32), features=np.zeros((0, 32), np.float32),
                      stamp=stamp)


def default_camera() -> CameraModel:
    """A placeholder camera model (1280x720, f=1000 px, looking along the radar boresight)."""
    K = np.array([[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]])
    T = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # radar -> OpenCV
    return CameraModel(K=K, image_size=(1280, 720), T_cam_radar=T)


class NoCamera(CameraSource):
    """No camera: never yields detections (the radar path runs alone)."""

    def __init__(self, cfg=None, **kw) -> None:
        self._camera = default_camera()

    @property
    def camera(self) -> CameraModel:
        return self._camera

    def read(self, timeout: float) -> Detections | None:
        import time

        time.sleep(min(timeout, 1.0))
        return None

    def close(self) -> None:
        pass
