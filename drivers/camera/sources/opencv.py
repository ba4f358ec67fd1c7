"""OpenCV VideoCapture backend: a device index, a V4L2 path, a GStreamer pipeline or a video file.

`device` strings: "0" (index), "/dev/video0" (V4L2), anything containing "!" (GStreamer
pipeline ending in appsink), else a video file path. Frames go through the ONNX detector,
descriptor, undistortion and depth (`DetectionStage`). Stamps: the host clock at grab time
minus `latency_s` (the camera's exposure-to-delivery delay, if known) for live devices; for a
video file, the file's position (CAP_PROP_POS_MSEC) from `start_stamp`. `read` blocks until
the device delivers a frame (V4L2 gives up after its own select timeout, ~10 s); run it on its
own thread (the vehicle loop does, as does `ResilientCamera`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from mmatch.drivers.camera.errors import CameraUnavailable, EndOfStream
from mmatch.drivers.camera.pipeline import DetectionStage
from mmatch.drivers.camera.sources.base import ImageCameraBase

log = logging.getLogger(__name__)


def parse_device(device: str | int) -> tuple[str | int, str]:
    """(argument for cv2.VideoCapture, kind) with kind one of index, v4l2, gstreamer, file."""
    if isinstance(device, int):
        return device, "index"
    s = str(device).strip()
    if s.isdigit():
        return int(s), "index"
    if "!" in s:
        return s, "gstreamer"
    if s.startswith("/dev/"):
        return s, "v4l2"
    return s, "file"


class OpenCvCamera(ImageCameraBase):
    """A camera read with cv2.VideoCapture, detections from a `DetectionStage`."""

    name = "opencv"

    def __init__(
        self,
        device: str | int,
        stage: DetectionStage,
        clock: Callable[[], float] = time.time,
        start_stamp: float | None = None,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        latency_s: float = 0.0,
    ) -> None:
        super().__init__(stage, clock)
        self.device = device
        self._arg, self.kind = parse_device(device)
        self.lossless = self.kind == "file"
        self._cap = None
        self._start_stamp = start_stamp
        self._size = (width, height)
        self._fps = fps
        self.latency_s = latency_s

    def open(self) -> None:
        import cv2

        if self.kind == "file" and not Path(self._arg).is_file():
            raise CameraUnavailable(f"camera {self.device!r}: no such video file")
        api = {"gstreamer": cv2.CAP_GSTREAMER, "v4l2": cv2.CAP_V4L2}.get(self.kind, cv2.CAP_ANY)
        cap = cv2.VideoCapture(self._arg, api)
        if not cap.isOpened():
            cap.release()
            raise CameraUnavailable(
                f"camera {self.device!r} ({self.kind}): cv2.VideoCapture could not open it"
            )
        if self.kind != "file":
            w, h = self._size if self._size[0] else self.stage.calibration.image_size
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, w)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, h)
            if self._fps:
                cap.set(cv2.CAP_PROP_FPS, self._fps)
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # newest frame, not a backlog
        if self._start_stamp is None:
            self._start_stamp = self.clock()
        self._cap = cap
        log.info("camera %r (%s) open", self.device, self.kind)

    def _grab(self, timeout: float) -> tuple[object, float] | None:
        import cv2

        if self._cap is None:
            self.open()
        ok, image = self._cap.read()
        if not ok:
            if self.kind == "file":
                raise EndOfStream(f"camera {self.device!r}: end of video file")
            raise CameraUnavailable(
                f"camera {self.device!r} ({self.kind}): no frame (device gone?)"
            )
        if self.kind == "file":
            stamp = self._start_stamp + self._cap.get(cv2.CAP_PROP_POS_MSEC) / 1e3
        else:
            stamp = self.clock() - self.latency_s
        return image, stamp

    def close(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()
