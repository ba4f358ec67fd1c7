"""INT8 quantization helper. The real quantization runs only where `onnx` is installed (it is
not a runtime dependency); without it the helper must fail with the install hint."""

import importlib.util

import numpy as np
import pytest

from mmatch.drivers.camera.errors import ModelError
from mmatch.drivers.camera.quantize import INSTALL_HINT, quantize_detector

from . import onnx_builder as ob

HAS_ONNX = importlib.util.find_spec("onnx") is not None


@pytest.mark.skipif(HAS_ONNX, reason="onnx installed: the hint path is not reachable")
def test_without_onnx_the_error_gives_the_install_hint(tmp_path):
    src = tmp_path / "m.onnx"
    src.write_bytes(ob.matmul_model(np.eye(4, 3)))
    with pytest.raises(ModelError, match="pip install onnx") as exc:
        quantize_detector(src, tmp_path / "q.onnx")
    assert INSTALL_HINT in str(exc.value)


def test_missing_source_names_file(tmp_path):
    with pytest.raises(ModelError, match=r"none\.onnx.*no such model file"):
        quantize_detector(tmp_path / "none.onnx", tmp_path / "q.onnx")


def test_dynamic_int8_on_a_small_model(tmp_path):
    pytest.importorskip("onnx")
    import onnxruntime as ort

    rng = np.random.default_rng(0)
    w = rng.normal(0, 1, (64, 32)).astype(np.float32)
    src = tmp_path / "m.onnx"
    src.write_bytes(ob.matmul_model(w))
    dst = quantize_detector(src, tmp_path / "m.int8.onnx", per_channel=False)
    x = rng.normal(0, 1, (16, 64)).astype(np.float32)
    ref = x @ w
    got = ort.InferenceSession(str(dst), providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    assert dst.stat().st_size < src.stat().st_size
    assert np.abs(got - ref).max() < 0.05 * np.abs(ref).max()


def _conv_detector(tmp_path):
    """Cells of an 8x8 grid: box = the cell, class-0 score = mean red of the cell (RGB input)."""
    k = 8
    w = np.zeros((6, 3, k, k), np.float32)
    b = np.zeros(6, np.float32)
    b[2] = b[3] = k  # w, h = one cell
    w[4, 0] = 1.0 / (k * k)  # class 0: mean of channel 0 (R when rgb=True), inputs scaled to 0..1
    w[5, 2] = 1.0 / (k * k)  # class 1: mean of channel 2 (B)
    # a conv cannot know where its cell is, so every box sits at the origin: the tests use
    # class-aware NMS
    # and check scores/classes only.
    src = tmp_path / "conv.onnx"
    src.write_bytes(ob.conv_detector_model(w, b))
    return src


def test_conv_model_runs_as_a_detector(tmp_path):
    from mmatch.drivers.camera.detector import DetectorConfig, OnnxDetector

    src = _conv_detector(tmp_path)
    det = OnnxDetector(
        DetectorConfig(
            model=str(src), kind="yolov8", letterbox=False, score_threshold=0.5, agnostic_nms=False
        )
    )
    img = np.zeros((64, 64, 3), np.uint8)
    img[:8, :8] = (0, 0, 255)  # red cell (BGR)
    img[8:16, 8:16] = (255, 0, 0)  # blue cell
    dec = det.detect(img)
    assert sorted(dec.classes.tolist()) == [0, 1]
    np.testing.assert_allclose(np.sort(dec.scores), [1.0, 1.0], atol=1e-5)


def test_static_qdq_int8_detector_matches_float(tmp_path):
    pytest.importorskip("onnx")
    from mmatch.drivers.camera.detector import DetectorConfig, OnnxDetector

    src = _conv_detector(tmp_path)
    rng = np.random.default_rng(1)
    calib = [rng.integers(0, 256, (64, 64, 3), dtype=np.uint8) for _ in range(8)]
    cfg = DetectorConfig(
        model=str(src), kind="yolov8", letterbox=False, score_threshold=0.5, agnostic_nms=False
    )
    dst = quantize_detector(
        src, tmp_path / "conv.int8.onnx", calibration_images=calib, detector_config=cfg
    )
    img = np.zeros((64, 64, 3), np.uint8)
    img[:8, :8] = (0, 0, 255)
    img[8:16, 8:16] = (255, 0, 0)
    f = OnnxDetector(cfg).detect(img)
    q = OnnxDetector(
        DetectorConfig(
            model=str(dst), kind="yolov8", letterbox=False, score_threshold=0.5, agnostic_nms=False
        )
    ).detect(img)
    assert sorted(q.classes.tolist()) == sorted(f.classes.tolist()) == [0, 1]
    np.testing.assert_allclose(np.sort(q.scores), np.sort(f.scores), atol=0.03)
    import onnx

    assert {"QuantizeLinear", "DequantizeLinear"} <= {
        n.op_type for n in onnx.load(str(dst)).graph.node
    }
