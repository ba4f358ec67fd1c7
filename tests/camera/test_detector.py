import numpy as np
import pytest

from mmatch.drivers.camera.calibration import validate
from mmatch.drivers.camera.depth import GroundPlane
from mmatch.drivers.camera.detector import DetectorConfig, OnnxDetector
from mmatch.drivers.camera.errors import ModelError
from mmatch.drivers.camera.pipeline import DetectionStage
from mmatch.errors import ConfigError

from . import onnx_builder as ob
from .camera_synth import COLOURS, painted_scene


def _write(tmp_path, name, data):
    p = tmp_path / name
    p.write_bytes(data)
    return str(p)


def _letterbox_encode(boxes_img, W=1280, H=720, S=640):
    """Image px -> network px for a 1280x720 image letterboxed into S x S (YOLO convention)."""
    r = min(S / W, S / H)
    px, py = (S - round(W * r)) // 2, (S - round(H * r)) // 2
    b = np.asarray(boxes_img, np.float32) * r
    b[:, [0, 2]] += px
    b[:, [1, 3]] += py
    return b


def _v8_output(net_boxes, classes, scores, nc=8, n=300, seed=0):
    rng = np.random.default_rng(seed)
    out = np.zeros((4 + nc, n), np.float32)
    xy = rng.uniform(0, 600, (n, 2))
    out[0:2] = xy.T
    out[2:4] = 20
    out[4:] = rng.uniform(0, 0.05, (nc, n))
    for k, (b, c, s) in enumerate(zip(net_boxes, classes, scores, strict=True)):
        for j, (shift, ds) in enumerate(
            ((0.0, 0.0), (2.0, 0.15))
        ):  # the box and a weaker duplicate
            col = 2 * k + j
            bb = b + shift
            out[:4, col] = ((bb[0] + bb[2]) / 2, (bb[1] + bb[3]) / 2, bb[2] - bb[0], bb[3] - bb[1])
            out[4:, col] = 0.0
            out[4 + c, col] = s - ds
    return out[None]


def test_painted_vehicles_detected_where_painted_and_told_apart(tmp_path):
    img, boxes, names = painted_scene()
    net = _letterbox_encode(boxes)
    out = _v8_output(net, classes=[2, 2, 7, 2, 5], scores=[0.9, 0.85, 0.8, 0.75, 0.7])
    model = _write(tmp_path, "v8.onnx", ob.constant_model({"output0": out}, (1, 3, 640, 640)))
    det = OnnxDetector(
        DetectorConfig(model=model, kind="yolov8", classes=(2, 5, 7), score_threshold=0.3)
    )
    assert det.input_size == (640, 640)
    calib = validate(
        [[800, 0, 640], [0, 800, 360], [0, 0, 1]],
        [],
        (1280, 720),
        np.eye(4),
        {"camera_height": 1.5, "pitch_deg": 0.0},
    )
    stage = DetectionStage(det.detect, calib)
    dets = stage.process(img, stamp=12.5)
    assert (
        dets.stamp == 12.5 and dets.boxes.dtype == np.float32 and dets.features.dtype == np.float32
    )
    assert dets.boxes.shape == (5, 6) and dets.features.shape == (5, 32)
    # Every painted vehicle is found once (duplicates suppressed), at its painted place (< 1 px).
    order = np.argsort(dets.boxes[:, 0])
    np.testing.assert_allclose(dets.boxes[order, :4], boxes[np.argsort(boxes[:, 0])], atol=1.0)
    np.testing.assert_array_equal(dets.boxes[:, 4], np.float32([0.9, 0.85, 0.8, 0.75, 0.7]))
    # Depth from the ground plane: contact point at Z = f h / (v2 - cy) (level camera), the
    # vehicle centre 1.5 m beyond it and 0.75 m up.
    for b in dets.boxes:
        z = 800 * 1.5 / (b[3] - 360)
        contact = np.array([((b[0] + b[2]) / 2 - 640) / 800 * z, 1.5, z])
        assert np.linalg.norm(contact) < b[5] < np.linalg.norm(contact) + 1.5
    assert (dets.depth_sigma > 0).all() and dets.depth_source == "ground"
    # Descriptors tell the colours apart: each box's dominant hue bin is its body colour's.
    for b, f in zip(dets.boxes, dets.features, strict=True):
        k = int(np.argmin(np.abs(boxes[:, 0] - b[0])))
        assert np.argmax(f[:16]) == COLOURS[names[k]][1] * 16 // 180
    feats = dets.features[np.argsort(dets.boxes[:, 0])]
    dist = np.abs(feats[:, None] - feats[None]).sum(-1)
    same = dist[0, 4]  # the two red cars
    assert same < 0.5 * min(dist[0, 1], dist[0, 2], dist[0, 3])


def test_yolov5_int8_model_runs_and_decodes(tmp_path):
    img, boxes, _ = painted_scene()
    net = _letterbox_encode(boxes[:2])
    rows = np.zeros((200, 5 + 3), np.float32)
    rows[:, :4] = (300, 300, 10, 10)
    for k, b in enumerate(net):
        rows[k, :4] = ((b[0] + b[2]) / 2, (b[1] + b[3]) / 2, b[2] - b[0], b[3] - b[1])
        rows[k, 4] = 0.9
        rows[k, 5 + k] = 1.0
    data, exact = ob.int8_constant_model({"output": rows[None]}, (1, 3, 640, 640))
    det = OnnxDetector(DetectorConfig(model=_write(tmp_path, "v5int8.onnx", data), kind="yolov5"))
    dec = det.detect(img)
    assert len(dec) == 2
    np.testing.assert_array_equal(dec.classes, [0, 1])
    # int8 quantisation error of the box coordinates (scale = max/127 ~ 3 network px ~ 6 image px)
    np.testing.assert_allclose(dec.boxes[np.argsort(dec.boxes[:, 0])], boxes[:2], atol=8.0)
    np.testing.assert_allclose(
        dec.scores, exact["output"][0, :2, 4] * exact["output"][0, [0, 1], [5, 6]], rtol=1e-6
    )


def test_centernet_model_with_depth_head(tmp_path):
    h, w = 160, 160  # 640 / stride 4
    hm = np.full((1, 2, h, w), -6.0, np.float32)
    wh = np.zeros((1, 2, h, w), np.float32)
    reg = np.zeros((1, 2, h, w), np.float32)
    dep = np.zeros((1, 1, h, w), np.float32)
    hm[0, 1, 80, 40] = 3.0  # sigmoid 0.95
    wh[0, :, 80, 40] = (20, 10)
    dep[0, 0, 80, 40] = -np.log(25.0)  # depth 25 m
    data = ob.constant_model({"hm": hm, "wh": wh, "reg": reg, "dep": dep}, (1, 3, 640, 640))
    det = OnnxDetector(
        DetectorConfig(model=_write(tmp_path, "cn.onnx", data), kind="centernet", letterbox=False)
    )
    img = np.zeros((320, 640, 3), np.uint8)  # stretched: x scale 1, y scale 2
    dec = det.detect(img)
    assert len(dec) == 1 and dec.classes[0] == 1
    np.testing.assert_allclose(
        dec.boxes[0], [(160 - 40), (320 - 20) / 2, (160 + 40), (320 + 20) / 2], atol=1e-3
    )
    assert dec.depth[0] == pytest.approx(25.0, rel=1e-4)
    calib = validate([[500, 0, 320], [0, 500, 160], [0, 0, 1]], [], (640, 320), np.eye(4))
    out = DetectionStage(det.detect, calib, ground=GroundPlane(1.5)).process(img, 1.0)
    assert out.depth_source == "model" and out.boxes[0, 5] == pytest.approx(25.0, rel=1e-4)


# ---- bad models fail at start, naming the file and what was expected ---------------------------


def test_missing_model_names_file(tmp_path):
    with pytest.raises(ModelError, match=r"nope\.onnx.*no such model file.*yolov8"):
        OnnxDetector(DetectorConfig(model=str(tmp_path / "nope.onnx")))


def test_garbage_model_names_file(tmp_path):
    p = _write(tmp_path, "junk.onnx", b"this is not a protobuf at all \x00\xff")
    with pytest.raises(ModelError, match=r"junk\.onnx.*not a loadable ONNX model"):
        OnnxDetector(DetectorConfig(model=p))


@pytest.mark.parametrize(
    "shape,match",
    [
        ((1, 640, 640, 3), r"NCHW.*looks like NHWC"),
        ((1, 1, 64, 64), r"\(1, 3, H, W\)"),
        ((1, 3, 64), r"\(1, 3, H, W\)"),
    ],
)
def test_wrong_input_shape(tmp_path, shape, match):
    p = _write(
        tmp_path, "bad_in.onnx", ob.constant_model({"output0": np.zeros((1, 6, 100))}, shape)
    )
    with pytest.raises(ModelError, match=r"bad_in\.onnx.*" + match):
        OnnxDetector(DetectorConfig(model=p))


def test_dynamic_input_needs_input_size(tmp_path):
    p = _write(
        tmp_path,
        "dyn.onnx",
        ob.constant_model({"output0": np.zeros((1, 6, 100))}, (1, 3, "h", "w")),
    )
    with pytest.raises(ModelError, match="input_size"):
        OnnxDetector(DetectorConfig(model=p))
    assert OnnxDetector(DetectorConfig(model=p, input_size=(320, 256))).input_size == (320, 256)
    with pytest.raises(ModelError, match="does not match"):
        OnnxDetector(
            DetectorConfig(
                model=_write(
                    tmp_path,
                    "s.onnx",
                    ob.constant_model({"output0": np.zeros((1, 6, 100))}, (1, 3, 64, 64)),
                ),
                input_size=(32, 32),
            )
        )


def test_wrong_output_layout(tmp_path):
    v5_layout = _write(
        tmp_path, "v5.onnx", ob.constant_model({"output0": np.zeros((1, 8400, 84))}, (1, 3, 64, 64))
    )
    with pytest.raises(
        ModelError, match=r"v5\.onnx.*expected one output \(1, 4 \+ C, N\).*yolov5 model"
    ):
        OnnxDetector(DetectorConfig(model=v5_layout, kind="yolov8"))
    assert OnnxDetector(DetectorConfig(model=v5_layout, kind="yolov5")).num_classes == 79
    b_out = np.zeros((1, 6, 100), np.float32)
    b_out[0, :, 3] = (32, 32, 10, 20, 0.9, 0.0)  # one box in output "b" only
    two = _write(
        tmp_path,
        "two.onnx",
        ob.constant_model({"a": np.zeros((1, 6, 100)), "b": b_out}, (1, 3, 64, 64)),
    )
    with pytest.raises(ModelError, match=r"two\.onnx.*one output.*output_name"):
        OnnxDetector(DetectorConfig(model=two))
    picked = OnnxDetector(DetectorConfig(model=two, output_name="b", letterbox=False))
    dec = picked.detect(np.zeros((64, 64, 3), np.uint8))
    assert len(dec) == 1 and dec.boxes[0].tolist() == [27.0, 22.0, 37.0, 42.0]
    with pytest.raises(ModelError, match=r"named 'c'"):
        OnnxDetector(DetectorConfig(model=two, output_name="c"))
    with pytest.raises(ModelError, match=r"classes"):
        OnnxDetector(
            DetectorConfig(
                model=_write(
                    tmp_path,
                    "v8.onnx",
                    ob.constant_model({"o": np.zeros((1, 8, 100))}, (1, 3, 64, 64)),
                ),
                classes=(2, 7),
            )
        )
    cn = _write(
        tmp_path,
        "cn.onnx",
        ob.constant_model(
            {"hm": np.zeros((1, 2, 16, 16)), "size": np.zeros((1, 2, 16, 16))}, (1, 3, 64, 64)
        ),
    )
    with pytest.raises(ModelError, match=r"cn\.onnx.*heatmap"):
        OnnxDetector(DetectorConfig(model=cn, kind="centernet"))


def test_config_from_dict_rejects_unknown_keys():
    with pytest.raises(ConfigError, match="scor_threshold"):
        DetectorConfig.from_dict({"model": "m.onnx", "scor_threshold": 0.3})
    with pytest.raises(ConfigError, match="detector.kind"):
        DetectorConfig.from_dict({"model": "m.onnx", "kind": "yolov3"})
    with pytest.raises(ConfigError, match="num_classes"):
        DetectorConfig.from_dict({"model": "m.onnx", "depth_index": 88})
    cfg = DetectorConfig.from_dict(
        {"model": "m.onnx", "classes": [2, 7], "input_size": [640, 384], "threads": 2}
    )
    assert cfg.classes == (2, 7) and cfg.input_size == (640, 384) and cfg.threads == 2


def test_identity_model_feeds_raw_output_through_decoder(tmp_path):
    """The decoder sees exactly the tensor the session returns (no hidden reshaping)."""
    import onnxruntime as ort

    s = ort.InferenceSession(ob.identity_model((1, 12, 50)), providers=["CPUExecutionProvider"])
    raw = np.zeros((1, 12, 50), np.float32)
    raw[0, :4, 7] = (50, 60, 20, 10)
    raw[0, 4 + 3, 7] = 0.8
    from mmatch.drivers.camera.decode import decode_yolov8

    dec = decode_yolov8(s.run(None, {"raw": raw})[0], 0.5)
    np.testing.assert_allclose(dec.boxes, [[40, 55, 60, 65]])
    assert dec.classes.tolist() == [3]
