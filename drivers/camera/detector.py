"""ONNX Runtime vehicle detector for non-OAK cameras (user-supplied model, no weights ship).

`OnnxDetector(DetectorConfig(model="yolov8n.onnx", kind="yolov8"))` loads the model, checks
its input (one NCHW 3-channel image tensor) and, with a dry run on a blank image, its output
layout against `kind`; any mismatch fails at start with a `ModelError` naming the file and
what was expected. `detect(image_bgr)` returns the kept boxes in *image* pixels.

INT8 models (from `mmatch.drivers.camera.quantize` or any QDQ/QOperator export) run the same way.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from mmatch.drivers.camera.decode import (
    KINDS,
    Decoded,
    decode_centernet,
    decode_yolov5,
    decode_yolov8,
    suppress,
)
from mmatch.drivers.camera.errors import ModelError
from mmatch.errors import ConfigError

log = logging.getLogger(__name__)

#: COCO class ids of vehicles (car, motorcycle, bus, truck), for COCO-trained detectors.
COCO_VEHICLES: tuple[int, ...] = (2, 3, 5, 7)
_CENTERNET_HEADS = ("hm", "wh", "reg", "dep")


@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings (the `[camera.detector]` table of a vehicle config).

    model: path of the .onnx file. kind: "yolov5" | "yolov8" | "centernet".
    input_size: (width, height) px fed to the network; required only when the model's input
        is dynamic, must match it otherwise.
    score_threshold: minimum final score (0-1); iou_threshold: NMS IoU.
    classes: class ids to keep (None: all); e.g. COCO_VEHICLES for a COCO detector.
    num_classes: number of class columns (None: all columns after the box/objectness ones);
        needed when the output carries extra columns such as a depth.
    depth_index: YOLO only: column (index in the per-anchor vector) of a per-box depth in metres.
    output_name: YOLO only: which output holds the predictions when the model has several
        (e.g. older exports that also output the raw heads, or -seg models); None: the only one.
    centernet_heads: output names of (heatmap, size, offset, depth); missing optional heads
        (offset, depth) are allowed. centernet_depth_is_metres: the depth head is metres
        (else CenterNet's 1/sigmoid(x) - 1). centernet_sigmoid: None decides from the values.
    letterbox: keep the aspect ratio and pad with `pad_value` (YOLO); False stretches.
    rgb: feed RGB (True) or BGR; scale, mean, std: input = (pixel * scale - mean) / std
        (ignored for uint8 inputs).
    threads: ONNX Runtime intra-op threads (1 keeps the radar path its core).
    """

    model: str
    kind: str = "yolov8"
    input_size: tuple[int, int] | None = None
    score_threshold: float = 0.25
    iou_threshold: float = 0.45
    classes: tuple[int, ...] | None = None
    num_classes: int | None = None
    depth_index: int | None = None
    centernet_heads: tuple[str, ...] = _CENTERNET_HEADS
    centernet_depth_is_metres: bool = False
    centernet_sigmoid: bool | None = None
    output_name: str | None = None
    letterbox: bool = True
    pad_value: int = 114
    rgb: bool = True
    scale: float = 1.0 / 255.0
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    threads: int = 1
    max_detections: int = 100
    pre_nms_top_k: int = 1000
    agnostic_nms: bool = True

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"detector.kind: {self.kind!r} is not one of {', '.join(KINDS)}")
        if not 0.0 < self.score_threshold < 1.0:
            raise ConfigError(f"detector.score_threshold: {self.score_threshold} not in (0, 1)")
        if not 0.0 < self.iou_threshold <= 1.0:
            raise ConfigError(f"detector.iou_threshold: {self.iou_threshold} not in (0, 1]")
        if self.threads < 1:
            raise ConfigError(f"detector.threads: {self.threads} must be >= 1")
        if self.input_size is not None and (len(self.input_size) != 2 or min(self.input_size) < 8):
            raise ConfigError(
                f"detector.input_size: {self.input_size} must be (width, height) >= 8 px"
            )
        if self.depth_index is not None and self.num_classes is None and self.kind != "centernet":
            raise ConfigError(
                "detector.depth_index: set detector.num_classes too, so the depth "
                "column is not read as a class"
            )

    @classmethod
    def from_dict(cls, d: dict) -> DetectorConfig:
        """Build from a parsed TOML/JSON table; unknown keys are rejected by name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(
                f"detector: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        if "model" not in d:
            raise ConfigError("detector.model: missing (path of the .onnx file)")
        kw = dict(d)
        for key in ("input_size", "classes", "centernet_heads", "mean", "std"):
            if kw.get(key) is not None:
                kw[key] = tuple(kw[key])
        return cls(**kw)


@dataclass
class Letterbox:
    """How an image was mapped into the network input: x_net = x_img * (sx, sy) + (px, py)."""

    sx: float
    sy: float
    px: float
    py: float

    def to_image(self, boxes: np.ndarray, width: int, height: int) -> np.ndarray:
        """(K, 4) network-input px -> image px, clipped to the image."""
        out = np.empty_like(boxes, dtype=np.float32)
        out[:, [0, 2]] = (boxes[:, [0, 2]] - self.px) / self.sx
        out[:, [1, 3]] = (boxes[:, [1, 3]] - self.py) / self.sy
        out[:, [0, 2]] = np.clip(out[:, [0, 2]], 0, width)
        out[:, [1, 3]] = np.clip(out[:, [1, 3]], 0, height)
        return out


class OnnxDetector:
    """A user-supplied ONNX detector run with ONNX Runtime on the CPU."""

    def __init__(self, config: DetectorConfig) -> None:
        self.config = config
        self.path = Path(config.model)
        self._session = self._load()
        self._input_name, self._input_dtype, self.input_size = self._check_input()
        self._output_names = [o.name for o in self._session.get_outputs()]
        self._check_outputs()

    # ---- start-up checks ------------------------------------------------------------------
    def _load(self):
        cfg = self.config
        if not self.path.is_file():
            raise ModelError(
                str(self.path), f"no such model file; expected an ONNX {cfg.kind} detector"
            )
        try:
            import onnxruntime as ort
        except ImportError as exc:  # pragma: no cover - onnxruntime is a runtime dependency
            raise ModelError(
                str(self.path), "onnxruntime is not installed (pip install onnxruntime)"
            ) from exc
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = cfg.threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.log_severity_level = 3
        try:
            return ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph/... types
            raise ModelError(
                str(self.path),
                f"not a loadable ONNX model ({type(exc).__name__}: "
                f"{str(exc).splitlines()[0] if str(exc) else ''})",
            ) from exc

    def _check_input(self) -> tuple[str, np.dtype, tuple[int, int]]:
        cfg = self.config
        inputs = self._session.get_inputs()
        expected = "one image input of shape (1, 3, H, W) (NCHW, 3 channels)"
        if len(inputs) != 1:
            raise ModelError(
                str(self.path),
                f"expected {expected}; model has {len(inputs)} inputs {[i.name for i in inputs]}",
            )
        inp = inputs[0]
        shape = list(inp.shape)
        if len(shape) != 4:
            raise ModelError(
                str(self.path), f"expected {expected}; input {inp.name!r} has shape {shape}"
            )
        if isinstance(shape[1], int) and shape[1] != 3:
            hint = " (looks like NHWC; export the model as NCHW)" if shape[3] == 3 else ""
            raise ModelError(
                str(self.path), f"expected {expected}; input {inp.name!r} has shape {shape}{hint}"
            )
        if isinstance(shape[0], int) and shape[0] != 1:
            raise ModelError(
                str(self.path), f"expected {expected}; input {inp.name!r} has batch {shape[0]}"
            )
        dtypes = {
            "tensor(float)": np.float32,
            "tensor(float16)": np.float16,
            "tensor(uint8)": np.uint8,
        }
        if inp.type not in dtypes:
            raise ModelError(
                str(self.path),
                f"expected a float32, float16 or uint8 input; input {inp.name!r} is {inp.type}",
            )
        h, w = shape[2], shape[3]
        static = isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0
        if static:
            if cfg.input_size is not None and tuple(cfg.input_size) != (w, h):
                raise ModelError(
                    str(self.path),
                    f"detector.input_size {tuple(cfg.input_size)} (w, h) "
                    f"does not match the model input {(w, h)}",
                )
            size = (w, h)
        else:
            if cfg.input_size is None:
                raise ModelError(
                    str(self.path),
                    f"input {inp.name!r} has dynamic size {shape}; "
                    "set detector.input_size = [width, height]",
                )
            size = tuple(cfg.input_size)
        return inp.name, np.dtype(dtypes[inp.type]), size

    def _check_outputs(self) -> None:
        """Dry run on a blank input and check the output layout against `kind`."""
        cfg = self.config
        w, h = self.input_size
        blank = np.zeros((1, 3, h, w), self._input_dtype)
        try:
            outs = self._session.run(None, {self._input_name: blank})
        except Exception as exc:
            raise ModelError(
                str(self.path),
                f"dry run on a blank (1, 3, {h}, {w}) input failed: "
                f"{type(exc).__name__}: {str(exc).splitlines()[0]}",
            ) from exc
        shapes = {n: tuple(o.shape) for n, o in zip(self._output_names, outs, strict=True)}
        if cfg.kind in ("yolov5", "yolov8"):
            self._check_yolo(shapes)
        else:
            self._check_centernet(shapes)
        log.info("detector %s: kind %s, input %dx%d, outputs %s", self.path, cfg.kind, w, h, shapes)

    def _fail(self, expected: str, shapes: dict) -> ModelError:
        return ModelError(
            str(self.path),
            f"output layout: expected {expected} for kind={self.config.kind!r}; "
            f"model outputs {shapes}",
        )

    def _check_yolo(self, shapes: dict) -> None:
        cfg = self.config
        v5 = cfg.kind == "yolov5"
        fixed = 5 if v5 else 4
        expected = (
            "one output (1, N, 5 + C) (cx, cy, w, h, obj, classes)"
            if v5
            else "one output (1, 4 + C, N) (cx, cy, w, h, classes)"
        )
        if cfg.output_name is not None:
            if cfg.output_name not in shapes:
                raise self._fail(
                    f"{expected} named {cfg.output_name!r} (detector.output_name)", shapes
                )
            shape = shapes[cfg.output_name]
        elif len(shapes) != 1:
            raise self._fail(f"{expected} (or set detector.output_name to one of them)", shapes)
        else:
            shape = next(iter(shapes.values()))
        if len(shape) != 3 or shape[0] != 1:
            raise self._fail(expected, shapes)
        width, n = (shape[2], shape[1]) if v5 else (shape[1], shape[2])
        if width < fixed + 1 or width > n:  # a detector has far more anchors than values per anchor
            other = "yolov8" if v5 else "yolov5"
            hint = f" (that is the transposed layout: is it a {other} model?)" if width > n else ""
            raise ModelError(
                str(self.path),
                f"output layout: expected {expected} for kind={cfg.kind!r}; "
                f"model outputs {shapes}{hint}",
            )
        nc = width - fixed if cfg.num_classes is None else cfg.num_classes
        if cfg.num_classes is not None and fixed + cfg.num_classes > width:
            raise self._fail(f"{expected} with C = num_classes = {cfg.num_classes}", shapes)
        if cfg.depth_index is not None and not fixed + nc <= cfg.depth_index < width:
            raise self._fail(
                f"{expected} plus a depth column at depth_index {cfg.depth_index} "
                f"(after the {nc} class columns)",
                shapes,
            )
        if cfg.classes is not None and (min(cfg.classes) < 0 or max(cfg.classes) >= nc):
            raise self._fail(f"{expected} with classes {cfg.classes} < C", shapes)
        self.num_classes = nc
        self._yolo_index = (
            0 if cfg.output_name is None else self._output_names.index(cfg.output_name)
        )

    def _heads(self, shapes: dict) -> list[str | None]:
        names = list(self.config.centernet_heads) + [None] * (4 - len(self.config.centernet_heads))
        return [n if n in shapes else None for n in names[:4]]

    def _check_centernet(self, shapes: dict) -> None:
        cfg = self.config
        hm, wh, reg, dep = self._heads(shapes)
        expected = (
            f"outputs named {cfg.centernet_heads[:2]} (heatmap (1, C, h, w), size (1, 2, h, w)) "
            "and "
            f"optionally {cfg.centernet_heads[2:]} (offset (1, 2, h, w), depth (1, 1, h, w))"
        )
        if hm is None or wh is None:
            raise self._fail(expected, shapes)
        s_hm = shapes[hm]
        if len(s_hm) != 4 or s_hm[0] != 1:
            raise self._fail(expected, shapes)
        hw = s_hm[2:]
        for name, ch in ((wh, 2), (reg, 2), (dep, 1)):
            if name is not None and shapes[name] != (1, ch, *hw):
                raise self._fail(expected, shapes)
        w, h = self.input_size
        if w / hw[1] != h / hw[0]:
            raise self._fail(
                f"{expected} with the same stride in x and y (input {w}x{h}, map {hw[1]}x{hw[0]})",
                shapes,
            )
        self.num_classes = s_hm[1]
        if cfg.classes is not None and (
            min(cfg.classes) < 0 or max(cfg.classes) >= self.num_classes
        ):
            raise self._fail(f"{expected} with classes {cfg.classes} < C", shapes)
        self.stride = w / hw[1]
        self._head_names = (hm, wh, reg, dep)

    # ---- per frame ------------------------------------------------------------------------
    def preprocess(self, image_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """BGR uint8 (H, W, 3) -> network input (1, 3, h, w) and the mapping back."""
        import cv2

        cfg = self.config
        H, W = image_bgr.shape[:2]
        w, h = self.input_size
        if cfg.letterbox:
            r = min(w / W, h / H)
            nw, nh = max(1, round(W * r)), max(1, round(H * r))
            resized = cv2.resize(image_bgr, (nw, nh), interpolation=cv2.INTER_LINEAR)
            px, py = (w - nw) // 2, (h - nh) // 2
            canvas = np.full((h, w, 3), cfg.pad_value, np.uint8)
            canvas[py : py + nh, px : px + nw] = resized
            lb = Letterbox(nw / W, nh / H, float(px), float(py))
        else:
            canvas = cv2.resize(image_bgr, (w, h), interpolation=cv2.INTER_LINEAR)
            lb = Letterbox(w / W, h / H, 0.0, 0.0)
        if cfg.rgb:
            canvas = canvas[:, :, ::-1]
        chw = np.ascontiguousarray(canvas.transpose(2, 0, 1))[None]
        if self._input_dtype == np.uint8:
            return chw, lb
        x = chw.astype(np.float32) * np.float32(cfg.scale)
        if any(cfg.mean) or any(s != 1.0 for s in cfg.std):
            x = (x - np.asarray(cfg.mean, np.float32)[:, None, None]) / np.asarray(
                cfg.std, np.float32
            )[:, None, None]
        return x.astype(self._input_dtype, copy=False), lb

    def decode(self, outputs: list[np.ndarray]) -> Decoded:
        """Raw session outputs -> NMS-kept candidates in network-input px."""
        cfg = self.config
        if cfg.kind == "centernet":
            by_name = dict(zip(self._output_names, outputs, strict=True))
            hm, wh, reg, dep = (by_name[n] if n else None for n in self._head_names)
            dec = decode_centernet(
                hm,
                wh,
                reg,
                dep,
                self.stride,
                cfg.score_threshold,
                cfg.classes,
                cfg.centernet_sigmoid,
                cfg.centernet_depth_is_metres,
                cfg.pre_nms_top_k,
            )
        else:
            fn = decode_yolov5 if cfg.kind == "yolov5" else decode_yolov8
            dec = fn(
                outputs[self._yolo_index],
                cfg.score_threshold,
                cfg.classes,
                cfg.num_classes,
                cfg.depth_index,
                cfg.pre_nms_top_k,
            )
        return suppress(dec, cfg.iou_threshold, cfg.agnostic_nms, cfg.max_detections)

    def detect(self, image_bgr: np.ndarray) -> Decoded:
        """Detect vehicles in a BGR uint8 image. Boxes come back in image px, clipped to it."""
        x, lb = self.preprocess(image_bgr)
        outputs = self._session.run(None, {self._input_name: x})
        dec = self.decode(outputs)
        H, W = image_bgr.shape[:2]
        dec.boxes = lb.to_image(dec.boxes, W, H)
        return dec


def timed_detect(detector: OnnxDetector, image: np.ndarray) -> tuple[Decoded, float]:
    """detect() and its wall time in ms."""
    t0 = time.perf_counter()
    dec = detector.detect(image)
    return dec, (time.perf_counter() - t0) * 1e3
