"""Real cameras for the vehicle service: the camera driver's OpenCV and OAK backends.

The driver (drivers/camera) owns the devices, the detector, monocular depth and the
descriptor; these adapters build its backend from the vehicle config and translate its
end-of-stream into ours. A camera that disappears raises DeviceError (CameraUnavailable)
from `read`; the loop reopens it while the radar path keeps running.
"""

from __future__ import annotations

import logging
from typing import Any

from mmatch.edge.config import VehicleConfig
from mmatch.edge.sources.base import CameraSource, EndOfStream
from mmatch.types import CameraModel, Detections

log = logging.getLogger(__name__)


class _DriverCamera(CameraSource):
    backend = ""

    def __init__(self, cfg: VehicleConfig, *, radar: Any = None, **kw: Any) -> None:
        from mmatch.drivers.camera.sources import open_camera

        height = getattr(radar, "radar_height", cfg.radar.height_m)
        self._cam = open_camera(self.backend, device=cfg.camera.device, calibration=cfg.camera.calibration,
                                model=cfg.camera.model, path=cfg.camera.path, threads=cfg.camera.threads,
                                radar_height=height)
        self.lossless = bool(getattr(self._cam, "lossless", False))

    @property
    def camera(self) -> CameraModel:
        return self._cam.camera

    def open(self) -> None:
        self._cam.open()

    def read(self, timeout: float) -> Detections | None:
        from mmatch.drivers.camera.errors import EndOfStream as DriverEnd

        try:
            return self._cam.read(timeout)
        except DriverEnd as exc:
            raise EndOfStream(str(exc)) from exc

    def counters(self) -> dict[str, int]:
        return dict(self._cam.counters())

    def close(self) -> None:
        self._cam.close()


class OpenCvCamera(_DriverCamera):
    """OpenCV VideoCapture (device index, V4L2 path, GStreamer pipeline, video file) + ONNX detector."""

    backend = "opencv"


class OakCamera(_DriverCamera):
    """Luxonis OAK through depthai, detection on the device."""

    backend = "oak"
