"""Luxonis OAK backend (depthai v3): camera + on-device detection network from a user model.

The model is the user's: an NN archive (`.tar.xz`, `.tar.gz`, `.tar`; from Luxonis HubAI or
`modelconverter`, carrying the parser config: YOLO/SSD family, classes, thresholds) or a bare
OpenVINO `.blob` (then `blob_*` settings describe the decoding). Nothing is downloaded: model
zoo slugs are refused.

Pipeline (`build_oak_pipeline`):
    Camera(CAM_A) --requestOutput(calibrated W x H, BGR888p)--> frame queue   (descriptors)
    Camera(CAM_A) --(NN input size, STRETCH)--> DetectionNetwork --> detection queue
The network sees the full field of view stretched to its input, so its normalised boxes scale
straight onto the calibrated image. Frames and detections are paired by sequence number.

Without a device, `OakCamera.open()` fails with `CameraUnavailable` naming what is missing
(no OAK found; the protocol setting; the validated model). Set DEPTHAI_TELEMETRY=0 (and
DEPTHAI_PROTOCOL=usb for USB-only) before depthai is imported; `import_depthai` sets those
defaults when the caller has not.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mmatch.drivers.camera.calibration import Calibration
from mmatch.drivers.camera.decode import Decoded
from mmatch.drivers.camera.depth import DepthConfig, GroundPlane
from mmatch.drivers.camera.errors import CameraUnavailable, ModelError
from mmatch.drivers.camera.pipeline import CameraDetections, DetectionStage, check_frame
from mmatch.drivers.camera.sources.base import CameraSource
from mmatch.errors import ConfigError
from mmatch.types import CameraModel

log = logging.getLogger(__name__)

ARCHIVE_SUFFIXES = (".tar.xz", ".tar.gz", ".tgz", ".tar")
_MAX_PENDING_FRAMES = 16  # colour frames kept while waiting for their detections


def import_depthai():
    """Import depthai with its network chatter off unless the caller chose otherwise."""
    os.environ.setdefault("DEPTHAI_TELEMETRY", "0")
    os.environ.setdefault("DEPTHAI_DISABLE_STARTUP_NOTIFICATIONS", "1")
    try:
        import depthai
    except ImportError as exc:
        raise CameraUnavailable(
            "the oak backend needs depthai (pip install 'mmatch[hardware]' or depthai>=3)"
        ) from exc
    return depthai


@dataclass(frozen=True)
class OakConfig:
    """OAK settings. model: NN archive or .blob path. fps: camera and network rate.
    confidence: on-device score threshold (0-1). device: MXID / IP / USB name ("" = first found).
    socket: camera board socket name (CAM_A = the colour camera). classes: class ids kept on
    the host (None: all). blob_*: decoding of a bare blob (an archive carries its own):
    input size (w, h), family "yolo" | "mobilenet", YOLO subtype (e.g. "yolov8"; "" for
    anchor-based v5 with `blob_anchors` / `blob_anchor_masks`), class count, NMS IoU.
    """

    model: str
    fps: float = 15.0
    confidence: float = 0.5
    device: str = ""
    socket: str = "CAM_A"
    classes: tuple[int, ...] | None = None
    queue_size: int = 4
    blob_input_size: tuple[int, int] | None = None
    blob_family: str = "yolo"
    blob_subtype: str = "yolov8"
    blob_num_classes: int = 80
    blob_iou: float = 0.5
    blob_anchors: tuple[float, ...] = ()
    blob_anchor_masks: dict | None = None

    def __post_init__(self) -> None:
        if not 0 < self.fps <= 240:
            raise ConfigError(f"oak.fps: {self.fps} not in (0, 240]")
        if not 0 < self.confidence < 1:
            raise ConfigError(f"oak.confidence: {self.confidence} not in (0, 1)")
        if self.blob_family not in ("yolo", "mobilenet"):
            raise ConfigError(f"oak.blob_family: {self.blob_family!r} is not yolo or mobilenet")


@dataclass
class OakModel:
    """A validated model: kind "archive" (with the parsed dai.NNArchive) or "blob"."""

    path: Path
    kind: str
    archive: object | None = None
    input_size: tuple[int, int] | None = None


def load_oak_model(dai, cfg: OakConfig) -> OakModel:
    """Check the model file without a device; ModelError names the file and what was expected."""
    path = Path(cfg.model)
    expected = "an NN archive (.tar.xz/.tar.gz/.tar) or an OpenVINO .blob"
    if not cfg.model:
        raise ModelError(
            "(none)", f"oak.model is empty; expected {expected} (zoo downloads are disabled)"
        )
    if not path.is_file():
        raise ModelError(str(path), f"no such model file; expected {expected}")
    name = path.name.lower()
    if name.endswith(ARCHIVE_SUFFIXES):
        try:
            archive = dai.NNArchive(str(path))
            size = tuple(archive.getInputSize())
        except Exception as exc:
            raise ModelError(
                str(path),
                f"not a readable NN archive ({exc}); expected {expected} with config.json + model",
            ) from exc
        return OakModel(path, "archive", archive, size)
    if name.endswith(".blob"):
        if cfg.blob_input_size is None:
            raise ModelError(
                str(path),
                "a bare .blob needs oak.blob_input_size = [width, height] "
                "(an NN archive carries it)",
            )
        try:
            dai.OpenVINO.Blob(str(path))
        except Exception as exc:
            raise ModelError(str(path), f"not a valid OpenVINO blob ({exc})") from exc
        return OakModel(path, "blob", None, tuple(cfg.blob_input_size))
    raise ModelError(str(path), f"unknown model type; expected {expected}")


@dataclass
class OakQueues:
    detections: object
    frames: object


def build_oak_pipeline(
    dai, pipeline, cfg: OakConfig, model: OakModel, image_size: tuple[int, int]
) -> OakQueues:
    """Create the camera + detection network nodes on `pipeline` and their host queues.

    image_size: (width, height) of the frames used for descriptors, = the calibration's.
    Needs a device-backed pipeline (dai.Pipeline() / dai.Pipeline(device)); a host-only one
    refuses device nodes.
    """
    socket = getattr(dai.CameraBoardSocket, cfg.socket)
    cam = pipeline.create(dai.node.Camera).build(socket)
    frames_out = cam.requestOutput(
        tuple(image_size), dai.ImgFrame.Type.BGR888p, dai.ImgResizeMode.STRETCH, cfg.fps
    )
    det = pipeline.create(dai.node.DetectionNetwork)
    if model.kind == "archive":
        det = det.build(cam, model.archive, cfg.fps, dai.ImgResizeMode.STRETCH)
    else:
        nn_in = cam.requestOutput(
            tuple(model.input_size), dai.ImgFrame.Type.BGR888p, dai.ImgResizeMode.STRETCH, cfg.fps
        )
        det.setBlobPath(str(model.path))
        parser = det.detectionParser
        family = (
            dai.DetectionNetworkType.YOLO
            if cfg.blob_family == "yolo"
            else dai.DetectionNetworkType.MOBILENET
        )
        parser.setNNFamily(family)
        parser.setNumClasses(cfg.blob_num_classes)
        parser.setIouThreshold(cfg.blob_iou)
        parser.setInputImageSize(*model.input_size)
        if cfg.blob_family == "yolo":
            parser.setCoordinateSize(4)
            if cfg.blob_subtype:
                parser.setSubtype(cfg.blob_subtype)
            if cfg.blob_anchors:
                parser.setAnchors(list(cfg.blob_anchors))
            if cfg.blob_anchor_masks:
                parser.setAnchorMasks(dict(cfg.blob_anchor_masks))
        nn_in.link(det.input)
    det.setConfidenceThreshold(cfg.confidence)
    return OakQueues(
        detections=det.out.createOutputQueue(maxSize=cfg.queue_size, blocking=False),
        frames=frames_out.createOutputQueue(maxSize=cfg.queue_size, blocking=False),
    )


def detections_to_decoded(
    img_detections, width: int, height: int, classes: tuple[int, ...] | None = None
) -> Decoded:
    """dai.ImgDetections (normalised xmin..ymax) -> Decoded in image px (clipped to the image)."""
    dets = list(img_detections.detections)
    if classes is not None:
        dets = [d for d in dets if d.label in classes]
    if not dets:
        return Decoded(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int32))
    a = np.array(
        [(d.xmin, d.ymin, d.xmax, d.ymax, d.confidence, d.label) for d in dets], np.float64
    )
    boxes = np.clip(a[:, :4], 0.0, 1.0) * np.array([width, height, width, height])
    return Decoded(boxes.astype(np.float32), a[:, 4].astype(np.float32), a[:, 5].astype(np.int32))


def device_stamp_to_shared(
    ts_seconds: float, now_wall: float | None = None, now_mono: float | None = None
) -> float:
    """depthai stamps are host steady-clock seconds (CLOCK_MONOTONIC); map to time.time()."""
    now_wall = time.time() if now_wall is None else now_wall
    now_mono = time.monotonic() if now_mono is None else now_mono
    return now_wall - (now_mono - ts_seconds)


class OakCamera(CameraSource):
    """An OAK camera detecting on the device; descriptors and depth on the host."""

    name = "oak"

    def __init__(
        self,
        config: OakConfig,
        calibration: Calibration,
        *,
        ground: GroundPlane | None = None,
        radar_height: float | None = None,
        depth: DepthConfig | None = None,
        pipeline_factory: Callable | None = None,
    ) -> None:
        self.config = config
        self.calibration = calibration
        self.stage = DetectionStage(None, calibration, ground, radar_height, depth)
        self._dai = import_depthai()
        self.model = load_oak_model(
            self._dai, config
        )  # fails here, before any device, on a bad model
        self._pipeline_factory = pipeline_factory
        self._pipeline = None
        self._queues: OakQueues | None = None
        self._frames: dict[int, object] = {}
        self._no_frame = 0

    @property
    def camera(self) -> CameraModel:
        return self.calibration.camera_model()

    def _new_pipeline(self):
        dai = self._dai
        if self._pipeline_factory is not None:
            return self._pipeline_factory()
        if self.config.device:
            return dai.Pipeline(dai.Device(dai.DeviceInfo(self.config.device)))
        return dai.Pipeline()

    def open(self) -> None:
        if self._pipeline is not None:
            return
        try:
            pipeline = self._new_pipeline()
        except RuntimeError as exc:
            which = (
                f"matching {self.config.device!r}" if self.config.device else "(first available)"
            )
            proto = os.environ.get("DEPTHAI_PROTOCOL", "any")
            raise CameraUnavailable(
                f"oak: no OAK device found {which} (depthai: {exc}; DEPTHAI_PROTOCOL={proto}). "
                f"Attach an OAK over USB (check `lsusb` for 03e7:) or PoE (unset DEPTHAI_PROTOCOL "
                f"or set it to tcpip); model {self.model.path} ({self.model.kind}) is ready"
            ) from exc
        try:
            self._queues = build_oak_pipeline(
                self._dai, pipeline, self.config, self.model, self.calibration.image_size
            )
            pipeline.start()
        except Exception as exc:
            try:
                pipeline.stop()
            except Exception:
                pass
            raise CameraUnavailable(
                f"oak: could not start the pipeline with {self.model.path}: {exc}"
            ) from exc
        self._pipeline = pipeline
        log.info("oak: pipeline running (%s, %s)", self.model.path, self.model.kind)

    def read(self, timeout: float) -> CameraDetections | None:
        if self._pipeline is None:
            self.open()
        deadline = time.monotonic() + timeout
        try:
            while True:
                if not self._pipeline.isRunning():
                    raise CameraUnavailable("oak: pipeline stopped (device disconnected?)")
                for f in self._queues.frames.tryGetAll() or []:
                    self._frames[f.getSequenceNum()] = f
                while (
                    len(self._frames) > _MAX_PENDING_FRAMES
                ):  # detections stalled: keep the newest
                    del self._frames[min(self._frames)]
                msg = self._queues.detections.tryGet()
                if msg is not None:
                    break
                if time.monotonic() >= deadline:
                    return None
                time.sleep(0.002)
        except CameraUnavailable:
            raise
        except Exception as exc:  # depthai raises RuntimeError / QueueException on a lost device
            raise CameraUnavailable(f"oak: device lost ({type(exc).__name__}: {exc})") from exc
        seq = msg.getSequenceNum()
        frame = self._frames.pop(seq, None)
        for k in [k for k in self._frames if k < seq]:
            del self._frames[k]
        stamp = device_stamp_to_shared(msg.getTimestamp().total_seconds())
        W, H = self.calibration.image_size
        image = frame.getCvFrame() if frame is not None else None
        self.stage.counters.frames += 1
        why = None if image is None else check_frame(image, (W, H))
        if why is not None:
            if why == "type":
                self.stage.counters.skipped_type += 1
            else:
                self.stage.counters.skipped_size += 1
            return None
        if image is None:
            self._no_frame += 1
        return self.stage.process_decoded(
            image, detections_to_decoded(msg, W, H, self.config.classes), stamp
        )

    def counters(self) -> dict[str, int]:
        out = self.stage.counters.as_dict()
        out["no_frame"] = self._no_frame
        return out

    def close(self) -> None:
        p, self._pipeline = self._pipeline, None
        self._queues = None
        self._frames.clear()
        if p is not None:
            try:
                p.stop()
            except Exception as exc:
                log.debug("oak: stop failed: %s", exc)


def calibration_from_oak(
    handler,
    image_size: tuple[int, int],
    T_cam_radar: np.ndarray,
    ground: dict | None = None,
    socket: str = "CAM_A",
    dai=None,
) -> Calibration:
    """A validated Calibration from an OAK's factory calibration (dai.CalibrationHandler, e.g.
    `device.readCalibration()`), for frames of `image_size` produced with STRETCH (the scaling
    this backend uses: fx, cx scale with width, fy, cy with height). The extrinsic to the radar
    is not on the device: give it (e.g. from `estimate_T_cam_radar`)."""
    from mmatch.drivers.camera.calibration import validate

    dai = dai or import_depthai()
    sock = getattr(dai.CameraBoardSocket, socket)
    w, h = image_size
    model = handler.getDistortionModel(sock)
    if "Perspective" not in str(model):
        raise ConfigError(
            f"oak: camera {socket} uses the {model} distortion model; only Perspective "
            "(OpenCV's pinhole + radial/tangential) is supported"
        )
    K = np.asarray(handler.getCameraIntrinsics(sock, w, h, keepAspectRatio=False), np.float64)
    dist = np.asarray(handler.getDistortionCoefficients(sock), np.float64)
    if dist.size > 14:
        dist = dist[:14]
    return validate(
        K, dist, (w, h), T_cam_radar, ground, path=f"<oak {socket} factory calibration>"
    )
