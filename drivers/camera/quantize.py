"""INT8 quantization of a user's ONNX detector with onnxruntime's tooling.

onnxruntime.quantization needs the `onnx` package, which is not a runtime dependency of
MMatch: it is imported here lazily, and a missing install fails with a clear hint
(`pip install onnx`, or the `quantize` extra). The quantized model then runs through
`OnnxDetector` like any other (checked at start like any other).

Two modes:
- dynamic (`quantize_detector(src, dst)`): weights to int8, activations quantized at run time.
  No calibration data; the usual first step for MatMul/Gemm-heavy models.
- static QDQ (`quantize_detector(src, dst, calibration_images=[...])`): weights and activations
  int8 with ranges calibrated on representative BGR images (a few dozen frames of the user's
  own camera), preprocessed exactly as the detector does. The usual choice for conv detectors.

Command line: `python -m mmatch.drivers.camera quantize yolov8n.onnx yolov8n.int8.onnx [--images ...]`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from mmatch.drivers.camera.errors import ModelError

log = logging.getLogger(__name__)

INSTALL_HINT = (
    "INT8 quantization needs the 'onnx' package: pip install onnx (or pip install 'mmatch[quantize]')"
)


def _quantization_module():
    try:
        import onnx  # noqa: F401 - onnxruntime.quantization imports it; fail here with a hint instead
        from onnxruntime import quantization
    except ImportError as exc:
        raise ModelError("(quantization)", INSTALL_HINT) from exc
    return quantization


def quantize_detector(
    src: str | Path,
    dst: str | Path,
    *,
    calibration_images: Iterable[np.ndarray] | None = None,
    detector_config=None,
    per_channel: bool = True,
) -> Path:
    """Write an INT8 version of the ONNX model `src` to `dst` and return `dst`.

    calibration_images: BGR uint8 images for static QDQ quantization (None: dynamic).
    detector_config: the DetectorConfig used to preprocess calibration images (its `model`
        must be `src`); built with defaults when None.
    """
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise ModelError(str(src), "no such model file to quantize")
    q = _quantization_module()
    if calibration_images is None:
        q.quantize_dynamic(
            str(src), str(dst), weight_type=q.QuantType.QInt8, per_channel=per_channel
        )
        log.info("quantized %s -> %s (dynamic int8)", src, dst)
        return dst
    from mmatch.drivers.camera.detector import DetectorConfig, OnnxDetector

    det = OnnxDetector(detector_config or DetectorConfig(model=str(src)))
    inputs = [{det._input_name: det.preprocess(img)[0]} for img in calibration_images]
    if not inputs:
        raise ModelError(str(src), "static quantization needs at least one calibration image")

    class _Reader(q.CalibrationDataReader):
        def __init__(self) -> None:
            self._it = iter(inputs)

        def get_next(self):
            return next(self._it, None)

    q.quantize_static(
        str(src),
        str(dst),
        _Reader(),
        quant_format=q.QuantFormat.QDQ,
        activation_type=q.QuantType.QInt8,
        weight_type=q.QuantType.QInt8,
        per_channel=per_channel,
    )
    log.info("quantized %s -> %s (static QDQ int8, %d calibration images)", src, dst, len(inputs))
    return dst
