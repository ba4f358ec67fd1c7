"""The depthai (v3) path without a device: model checks, pipeline wiring, clear failure."""

import io
import json
import os
import tarfile
import time
from datetime import timedelta

import numpy as np
import pytest

dai = pytest.importorskip("depthai")

from mmatch.drivers.camera.calibration import validate  # noqa: E402
from mmatch.drivers.camera.errors import CameraUnavailable, ModelError  # noqa: E402
from mmatch.drivers.camera.sources.oak import (  # noqa: E402
    OakCamera,
    OakConfig,
    OakModel,
    build_oak_pipeline,  # noqa: E402
    detections_to_decoded,
    device_stamp_to_shared,
    load_oak_model,
)

W, H = 640, 400
CALIB = validate(
    [[500, 0, 320], [0, 500, 200], [0, 0, 1]], [], (W, H), np.eye(4), {"camera_height": 1.3}
)


def make_archive(path, input_size=(64, 64)):
    """A minimal NN archive (config.json + model file), as HubAI/modelconverter produce."""
    w, h = input_size
    cfg = {
        "config_version": "1.0",
        "model": {
            "metadata": {"name": "tiny-vehicles", "path": "tiny.onnx", "precision": "float32"},
            "inputs": [
                {
                    "name": "images",
                    "dtype": "float32",
                    "input_type": "image",
                    "shape": [1, 3, h, w],
                    "layout": "NCHW",
                    "preprocessing": {
                        "mean": [0, 0, 0],
                        "scale": [255, 255, 255],
                        "reverse_channels": False,
                        "interleaved_to_planar": False,
                    },
                }
            ],
            "outputs": [
                {"name": "output0", "dtype": "float32", "shape": [1, 6, 84], "layout": "NCD"}
            ],
            "heads": [
                {
                    "parser": "YOLO",
                    "outputs": ["output0"],
                    "metadata": {
                        "postprocessor_path": None,
                        "classes": ["car", "truck"],
                        "n_classes": 2,
                        "iou_threshold": 0.5,
                        "conf_threshold": 0.5,
                        "max_det": 100,
                        "anchors": None,
                        "subtype": "yolov8",
                        "yolo_outputs": ["output0"],
                    },
                }
            ],
        },
    }
    with tarfile.open(path, "w:xz") as tar:
        for name, data in (("config.json", json.dumps(cfg).encode()), ("tiny.onnx", b"\x08\x08")):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return str(path)


def test_env_is_quiet():
    assert os.environ["DEPTHAI_TELEMETRY"] == "0" and os.environ["DEPTHAI_PROTOCOL"] == "usb"


def test_model_checks_without_device(tmp_path):
    arch = load_oak_model(dai, OakConfig(model=make_archive(tmp_path / "m.tar.xz", (96, 64))))
    assert arch.kind == "archive" and arch.input_size == (96, 64)
    with pytest.raises(ModelError, match=r"nope\.tar\.xz.*no such model file.*NN archive"):
        load_oak_model(dai, OakConfig(model=str(tmp_path / "nope.tar.xz")))
    (tmp_path / "bad.tar.xz").write_bytes(b"garbage")
    with pytest.raises(ModelError, match=r"bad\.tar\.xz.*not a readable NN archive"):
        load_oak_model(dai, OakConfig(model=str(tmp_path / "bad.tar.xz")))
    (tmp_path / "m.blob").write_bytes(b"garbage")
    with pytest.raises(ModelError, match=r"m\.blob.*blob_input_size"):
        load_oak_model(dai, OakConfig(model=str(tmp_path / "m.blob")))
    with pytest.raises(ModelError, match=r"m\.blob.*not a valid OpenVINO blob"):
        load_oak_model(dai, OakConfig(model=str(tmp_path / "m.blob"), blob_input_size=(416, 416)))
    (tmp_path / "m.onnx").write_bytes(b"x")
    with pytest.raises(ModelError, match=r"m\.onnx.*unknown model type"):
        load_oak_model(dai, OakConfig(model=str(tmp_path / "m.onnx")))
    with pytest.raises(ModelError, match="zoo"):
        load_oak_model(dai, OakConfig(model=""))


def test_no_device_fails_clearly_and_fast(tmp_path):
    cam = OakCamera(OakConfig(model=make_archive(tmp_path / "m.tar.xz")), CALIB)
    t0 = time.monotonic()
    with pytest.raises(CameraUnavailable) as exc:
        cam.open()
    assert time.monotonic() - t0 < 10  # DEPTHAI_PROTOCOL=usb: no 11 s network search
    msg = str(exc.value)
    assert "no OAK device found" in msg and "DEPTHAI_PROTOCOL=usb" in msg and "m.tar.xz" in msg
    cam.close()
    cam.close()


def test_host_only_pipeline_refuses_device_nodes_in_our_builder(tmp_path):
    """Our builder calls the real v3 API (Pipeline.create(node.Camera) ...) up to the device
    node."""
    model = load_oak_model(dai, OakConfig(model=make_archive(tmp_path / "m.tar.xz")))
    p = dai.Pipeline(False)
    with pytest.raises(RuntimeError, match="host only"):
        build_oak_pipeline(dai, p, OakConfig(model=str(model.path)), model, (W, H))


# ---- wiring, checked against a recording stand-in for depthai --------------------------------


class Rec:
    """Records every attribute access and call as a path, returns itself (or given values)."""

    def __init__(self, log, name="dai"):
        self._log, self._name = log, name

    def __getattr__(self, item):
        return Rec(self._log, f"{self._name}.{item}")

    def __call__(self, *args, **kw):
        self._log.append((self._name, args, kw))
        return Rec(self._log, f"{self._name}()")

    def __repr__(self):
        return self._name


def test_pipeline_wiring_archive_and_blob(tmp_path):
    log = []
    fake_dai, pipe = Rec(log, "dai"), Rec(log, "pipeline")
    cfg = OakConfig(model="m.tar.xz", fps=12.0, confidence=0.4)
    build_oak_pipeline(
        fake_dai, pipe, cfg, OakModel(tmp_path / "m.tar.xz", "archive", "ARCHIVE", (64, 64)), (W, H)
    )
    calls = [(n, tuple(map(repr, a))) for n, a, _ in log]
    assert ("pipeline.create", ("dai.node.Camera",)) in calls
    assert ("pipeline.create().build", ("dai.CameraBoardSocket.CAM_A",)) in calls
    assert (
        "pipeline.create().build().requestOutput",
        ("(640, 400)", "dai.ImgFrame.Type.BGR888p", "dai.ImgResizeMode.STRETCH", "12.0"),
    ) in calls
    assert ("pipeline.create", ("dai.node.DetectionNetwork",)) in calls
    assert any(
        n == "pipeline.create().build"
        and a[1:] == ("'ARCHIVE'", "12.0", "dai.ImgResizeMode.STRETCH")
        for n, a in calls
    )
    assert ("pipeline.create().build().setConfidenceThreshold", ("0.4",)) in calls
    assert sum(n.endswith("createOutputQueue") for n, _ in calls) == 2
    log.clear()
    cfg = OakConfig(
        model="y.blob", blob_input_size=(416, 416), blob_num_classes=3, blob_subtype="yolov8"
    )
    build_oak_pipeline(
        fake_dai, pipe, cfg, OakModel(tmp_path / "y.blob", "blob", None, (416, 416)), (W, H)
    )
    calls = [(n, tuple(map(repr, a))) for n, a, _ in log]
    assert ("pipeline.create().setBlobPath", (repr(str(tmp_path / "y.blob")),)) in calls
    assert ("pipeline.create().detectionParser.setNumClasses", ("3",)) in calls
    assert ("pipeline.create().detectionParser.setSubtype", ("'yolov8'",)) in calls
    assert ("pipeline.create().detectionParser.setInputImageSize", ("416", "416")) in calls
    assert ("pipeline.create().build().requestOutput().link", ("pipeline.create().input",)) in calls


# ---- host side: detections + frames -> Detections ---------------------------------------------


def _img_detections(rows, seq, ts):
    d = dai.ImgDetections()
    dets = []
    for xmin, ymin, xmax, ymax, conf, label in rows:
        x = dai.ImgDetection()
        x.xmin, x.ymin, x.xmax, x.ymax, x.confidence, x.label = xmin, ymin, xmax, ymax, conf, label
        dets.append(x)
    d.detections = dets
    d.setSequenceNum(seq)
    d.setTimestamp(timedelta(seconds=ts))
    return d


def test_detections_to_decoded():
    msg = _img_detections(
        [(0.1, 0.2, 0.3, 0.4, 0.9, 2), (-0.1, 0.5, 0.5, 1.2, 0.6, 7), (0.5, 0.5, 0.6, 0.6, 0.7, 0)],
        1,
        0.0,
    )
    dec = detections_to_decoded(msg, W, H, classes=(2, 7))
    np.testing.assert_allclose(dec.boxes, [[64, 80, 192, 160], [0, 200, 320, 400]], atol=1e-3)
    np.testing.assert_allclose(dec.scores, [0.9, 0.6], atol=1e-6)
    assert dec.classes.tolist() == [2, 7]
    assert len(detections_to_decoded(dai.ImgDetections(), W, H)) == 0


def test_device_stamp_to_shared():
    assert device_stamp_to_shared(100.0, now_wall=5000.0, now_mono=100.25) == pytest.approx(4999.75)


class FakeFrame:
    def __init__(self, seq, image):
        self.seq, self.image = seq, image

    def getSequenceNum(self):
        return self.seq

    def getCvFrame(self):
        return self.image


class FakeQueue:
    def __init__(self, items):
        self.items = list(items)

    def tryGet(self):
        return self.items.pop(0) if self.items else None

    def tryGetAll(self):
        out, self.items = self.items, []
        return out


class FakePipeline:
    def __init__(self):
        self.running = True
        self.stopped = 0

    def isRunning(self):
        return self.running

    def start(self):
        pass

    def stop(self):
        self.stopped += 1


def test_oak_camera_read_pairs_frames_and_reports_loss(tmp_path, monkeypatch):
    red = np.zeros((H, W, 3), np.uint8)
    red[:, :] = (30, 30, 200)
    now = time.monotonic()
    dets = FakeQueue(
        [
            _img_detections([(0.25, 0.25, 0.5, 0.75, 0.8, 2)], 5, now),
            _img_detections([(0.25, 0.25, 0.5, 0.75, 0.8, 2)], 6, now + 0.05),
        ]
    )
    frames = FakeQueue([FakeFrame(5, red), FakeFrame(6, np.zeros((H // 2, W // 2, 3), np.uint8))])
    pipe = FakePipeline()
    import mmatch.drivers.camera.sources.oak as oak

    monkeypatch.setattr(oak, "build_oak_pipeline", lambda *a, **k: oak.OakQueues(dets, frames))
    cam = OakCamera(
        OakConfig(model=make_archive(tmp_path / "m.tar.xz")), CALIB, pipeline_factory=lambda: pipe
    )
    with cam:
        d = cam.read(0.5)
        np.testing.assert_allclose(d.boxes[0, :4], [160, 100, 320, 300], atol=1e-3)
        assert d.boxes[0, 4] == pytest.approx(0.8) and d.boxes[0, 5] > 0
        assert np.argmax(d.features[0, :16]) == 0  # descriptor from the paired red frame
        assert abs(d.stamp - time.time()) < 1.0
        assert cam.read(0.5) is None  # paired frame has the wrong size
        assert cam.counters()["skipped_size"] == 1
        assert cam.read(0.02) is None  # nothing more within the timeout
        pipe.running = False
        with pytest.raises(CameraUnavailable, match="pipeline stopped"):
            cam.read(0.1)
    assert pipe.stopped == 1


def test_calibration_from_factory_handler(tmp_path):
    from mmatch.drivers.camera.calibration import dumps_calibration, load_calibration
    from mmatch.drivers.camera.sources.oak import calibration_from_oak

    h = dai.CalibrationHandler()
    h.setCameraIntrinsics(
        dai.CameraBoardSocket.CAM_A, [[1500.0, 0, 960], [0, 1500.0, 540], [0, 0, 1]], 1920, 1080
    )
    h.setDistortionCoefficients(dai.CameraBoardSocket.CAM_A, [-0.1, 0.02] + [0.0] * 12)
    T = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0.1], [0, 1, 0, 0.05], [0, 0, 0, 1]])
    c = calibration_from_oak(h, (640, 400), T, {"camera_height": 1.2})
    np.testing.assert_allclose(
        c.K, [[500, 0, 320], [0, 1500 * 400 / 1080, 200], [0, 0, 1]], rtol=1e-6
    )
    assert c.dist.shape == (14,) and c.dist[0] == pytest.approx(-0.1)
    p = tmp_path / "oak.toml"
    p.write_text(dumps_calibration(c))
    again = load_calibration(p)
    np.testing.assert_array_equal(again.K, c.K)


def test_frames_waiting_for_detections_are_bounded(tmp_path, monkeypatch):
    import mmatch.drivers.camera.sources.oak as oak

    frames = FakeQueue([FakeFrame(i, np.zeros((H, W, 3), np.uint8)) for i in range(100)])
    monkeypatch.setattr(
        oak, "build_oak_pipeline", lambda *a, **k: oak.OakQueues(FakeQueue([]), frames)
    )
    cam = OakCamera(
        OakConfig(model=make_archive(tmp_path / "m.tar.xz")), CALIB, pipeline_factory=FakePipeline
    )
    with cam:
        assert cam.read(0.01) is None
        assert len(cam._frames) == oak._MAX_PENDING_FRAMES and max(cam._frames) == 99
