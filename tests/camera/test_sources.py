import time

import cv2
import numpy as np
import pytest

from mmatch.drivers.camera.calibration import validate
from mmatch.drivers.camera.decode import Decoded
from mmatch.drivers.camera.errors import CameraUnavailable, EndOfStream, ModelError
from mmatch.drivers.camera.pipeline import DetectionStage
from mmatch.drivers.camera.resilient import ResilientCamera
from mmatch.drivers.camera.sources import open_camera
from mmatch.drivers.camera.sources.base import CameraSource
from mmatch.drivers.camera.sources.opencv import OpenCvCamera, parse_device
from mmatch.drivers.camera.sources.replay import ReplayCamera
from mmatch.errors import ConfigError
from mmatch.types import CameraModel, Detections

from . import onnx_builder as ob
from .camera_synth import painted_scene

W, H = 320, 240
CALIB = validate(
    [[300, 0, 160], [0, 300, 120], [0, 0, 1]], [], (W, H), np.eye(4), {"camera_height": 1.2}
)


def fixed_detector(image):
    """A stand-in detector: one box in the middle of the image."""
    return Decoded(
        np.array([[100, 80, 200, 180]], np.float32),
        np.array([0.9], np.float32),
        np.array([2], np.int32),
    )


def _stage():
    return DetectionStage(fixed_detector, CALIB)


def test_parse_device():
    assert parse_device("0") == (0, "index") and parse_device(2) == (2, "index")
    assert parse_device("/dev/video1") == ("/dev/video1", "v4l2")
    assert parse_device("videotestsrc ! videoconvert ! appsink")[1] == "gstreamer"
    assert parse_device("drive.mp4") == ("drive.mp4", "file")


def test_opencv_video_file_end_to_end(tmp_path):
    path = str(tmp_path / "clip.avi")
    vw = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (W, H))
    assert vw.isOpened()
    for i in range(5):
        img = np.full((H, W, 3), 40 * i, np.uint8)
        img[80:180, 100:200] = (30, 30, 200)
        vw.write(img)
    vw.release()
    with OpenCvCamera(path, _stage(), start_stamp=100.0) as cam:
        assert cam.lossless and cam.camera.image_size == (W, H)
        got = []
        with pytest.raises(EndOfStream):
            while True:
                got.append(cam.read(1.0))
    assert len(got) == 5
    stamps = [d.stamp for d in got]
    assert stamps[0] == pytest.approx(100.0) and np.allclose(np.diff(stamps), 0.1, atol=1e-3)
    for d in got:
        assert d.boxes.shape == (1, 6) and d.boxes[0, 4] == pytest.approx(0.9)
        assert np.argmax(d.features[0, :16]) == 0  # the red patch fills the box
    assert cam.counters()["frames"] == 5 and cam.counters()["detections"] == 5
    cam.close()  # safe twice


def test_opencv_missing_devices_raise_device_errors(tmp_path):
    with pytest.raises(CameraUnavailable, match="no such video file"):
        OpenCvCamera(str(tmp_path / "none.mp4"), _stage()).open()
    with pytest.raises(CameraUnavailable, match=r"/dev/video97.*could not open"):
        OpenCvCamera("/dev/video97", _stage()).open()


def test_wrong_frames_are_skipped_and_counted():
    good = np.zeros((H, W, 3), np.uint8)
    frames = [
        (0.0, good),
        (0.1, np.zeros((H + 1, W, 3), np.uint8)),
        (0.2, good.astype(np.float32)),
        (0.3, np.zeros((H, W), np.uint8)),
        (0.4, None),
        (0.5, good),
    ]
    cam = ReplayCamera(frames=frames, stage=_stage())
    out = []
    with pytest.raises(EndOfStream):
        while True:
            out.append(cam.read(0.1))
    assert [d is not None for d in out] == [True, False, False, False, False, True]
    c = cam.counters()
    assert c["stage_skipped_size"] == 1 and c["stage_skipped_type"] == 3 and c["stage_frames"] == 6
    assert c["skipped"] == 4


def test_replay_image_folder_with_stamps_and_detector(tmp_path):
    img, boxes, _ = painted_scene()
    small = cv2.resize(img, (W, H))
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"f{i:03d}.png"), small)
    (tmp_path / "stamps.csv").write_text(
        "# name,stamp\nf000.png,10.0\nf001.png,10.05\nf002.png,10.1\n"
    )
    slept = []
    cam = ReplayCamera(tmp_path, stage=_stage(), realtime=True, sleep=slept.append)
    dets = [cam.read(0.1) for _ in range(3)]
    with pytest.raises(EndOfStream):
        cam.read(0.1)
    assert [d.stamp for d in dets] == [10.0, 10.05, 10.1]
    assert len(slept) == 2 and all(
        0.0 < s <= 0.05 + 1e-6 for s in slept
    )  # paced at the recorded rate
    assert cam.camera.image_size == (W, H)


def test_replay_scene_folder(tmp_path):
    from mmatch.scene_io import save_scene
    from mmatch.sim.scenario import make_scene

    for i in range(2):
        save_scene(tmp_path / f"s{i}.npz", make_scene(3, i, "easy"))
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    cam = ReplayCamera(tmp_path, role="cav")
    assert isinstance(cam.camera, CameraModel)
    d0, d1 = cam.read(0.1), cam.read(0.1)
    with pytest.raises(EndOfStream):
        cam.read(0.1)
    from mmatch.scene_io import load_scene

    ref = load_scene(tmp_path / "s1.npz").cav
    np.testing.assert_array_equal(d1.boxes, ref.boxes)
    np.testing.assert_array_equal(d1.features, ref.features)
    assert d1.stamp == ref.stamp and d0.features.shape[1] == 32


def test_sim_camera_on_a_fake_clock():
    now = [1000.0]
    slept = []

    def sleep(s):
        slept.append(s)
        now[0] += s

    cam = open_camera("sim", seed=2, mode="easy", role="ego", rate_hz=10.0)
    cam.clock, cam._sleep = (lambda: now[0]), sleep
    dets = [cam.read(1.0) for _ in range(3)]
    assert [round(d.stamp, 6) for d in dets] == [1000.1, 1000.2, 1000.3]
    assert all(d.boxes.shape[1] == 6 and d.features.shape[1] == 32 for d in dets)
    assert cam.read(0.01) is None  # next frame is 0.1 s away
    assert cam.camera.K.shape == (3, 3)


def test_open_camera_checks_at_start(tmp_path):
    calib = tmp_path / "c.toml"
    from mmatch.drivers.camera.calibration import dumps_calibration

    calib.write_text(dumps_calibration(CALIB))
    with pytest.raises(ModelError, match="missing.onnx"):
        open_camera("opencv", calibration=str(calib), model=str(tmp_path / "missing.onnx"))
    with pytest.raises(ConfigError, match="camera.model"):
        open_camera("opencv", calibration=str(calib))
    with pytest.raises(ConfigError, match="unknown backend"):
        open_camera("usb")
    model = tmp_path / "det.onnx"
    model.write_bytes(
        ob.constant_model({"output0": np.zeros((1, 7, 50), np.float32)}, (1, 3, 64, 64))
    )
    (tmp_path / "det.toml").write_text('kind = "yolov8"\nscore_threshold = 0.4\nclasses = [1, 2]\n')
    cam = open_camera("opencv", device="3", calibration=str(calib), model=str(model), threads=1)
    assert isinstance(cam, OpenCvCamera) and cam.stage is not None
    (tmp_path / "det.toml").write_text('kind = "yolov8"\nscore = 0.4\n')
    with pytest.raises(ConfigError, match="score"):
        open_camera("opencv", calibration=str(calib), model=str(model))


# ---- a camera that disappears never stops the radar loop ----------------------------------------


class FlakyCamera(CameraSource):
    """Gives `good` frames, then 'disappears' (DeviceError); opens fail as `plan` says."""

    opens: list[float] = []
    plan: list[str] = []

    def __init__(self, good=3):
        self.good = good
        self.n = 0

    @property
    def camera(self):
        return CALIB.camera_model()

    def open(self):
        FlakyCamera.opens.append(time.monotonic())
        if FlakyCamera.plan and FlakyCamera.plan.pop(0) == "fail":
            raise CameraUnavailable("flaky: not there")

    def read(self, timeout):
        if self.n >= self.good:
            raise CameraUnavailable("flaky: unplugged")
        self.n += 1
        time.sleep(0.002)
        return Detections(
            np.zeros((0, 6), np.float32), np.zeros((0, 32), np.float32), stamp=time.time()
        )

    def close(self):
        pass


def test_resilient_camera_reconnects_with_backoff_and_never_raises(caplog):
    FlakyCamera.opens = []
    FlakyCamera.plan = ["ok", "fail", "fail", "ok", "ok"]
    cam = ResilientCamera(
        lambda: FlakyCamera(good=3), backoff_s=0.01, max_backoff_s=0.04, name="cam0"
    )
    got = 0
    loops = 0
    with cam:
        deadline = time.monotonic() + 10
        while got < 6 and time.monotonic() < deadline:  # "the radar loop"
            loops += 1
            if cam.read(0.05) is not None:
                got += 1
            cam.latest(max_age_s=1.0)
    assert got >= 6
    c = cam.counters()
    assert c["failures"] >= 3 and c["opens"] >= 2 and c["frames"] >= 6
    assert "cam0 failed (CameraUnavailable: flaky: unplugged); retrying in 0.01 s" in caplog.text
    assert "cam0: back after 3 failure(s)" in caplog.text
    # backoff doubles while the device stays away (waits are never shorter than asked)
    gaps = np.diff(FlakyCamera.opens[:4])
    assert gaps[1] >= 0.02 - 1e-3 and gaps[2] >= 0.04 - 1e-3
    assert cam.state == "closed"
    cam.close()


def test_resilient_camera_on_a_missing_device_keeps_returning_none():
    stage = _stage()
    cam = ResilientCamera(
        lambda: OpenCvCamera("/dev/video98", stage), backoff_s=0.01, max_backoff_s=0.02
    )
    with cam:
        t0 = time.monotonic()
        results = [cam.read(0.02) for _ in range(10)]
        assert time.monotonic() - t0 < 5
        assert results == [None] * 10
        assert cam.latest() is None
        time.sleep(0.1)
        assert cam.state == "reconnecting" and "video98" in cam.last_error
        assert cam.counters()["failures"] >= 2


def test_resilient_camera_stops_on_config_errors_and_end_of_stream():
    def bad():
        raise ModelError("m.onnx", "no such model file")

    cam = ResilientCamera(bad, backoff_s=0.01).start()
    assert cam.read(1.0) is None
    assert cam.state == "failed" and "m.onnx" in cam.last_error
    cam.close()
    frames = [
        Detections(np.zeros((0, 6), np.float32), np.zeros((0, 32), np.float32), stamp=float(i))
        for i in range(3)
    ]
    cam = ResilientCamera(
        lambda: ReplayCamera(frames=frames, calibration=CALIB), backoff_s=0.01
    ).start()
    seen = []
    while True:
        d = cam.read(1.0)
        if d is None:
            break
        seen.append(d.stamp)
    cam.close()
    assert cam.state == "finished" and seen[-1] == 2.0
