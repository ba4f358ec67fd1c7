"""Source backends: registry, sim timing and views, DCA1000 against the fake FPGA, camera faults."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from mmatch.edge import config
from mmatch.edge.loop import SensorReader
from mmatch.edge.sources import open_camera, open_radar
from mmatch.edge.sources.base import NoCamera
from mmatch.edge.sources.sim import SimCamera, SimRadar
from mmatch.errors import ConfigError
from netutil import free_port



def test_unknown_backend_is_refused_by_name():
    cfg = config.from_dict({"radar": {"source": "sim"}})
    object.__setattr__(cfg.radar, "source", "lidar")
    with pytest.raises(ConfigError, match="radar.source: unknown backend 'lidar'"):
        open_radar(cfg)


def test_none_camera():
    cfg = config.from_dict({"camera": {"source": "none"}})
    cam = open_camera(cfg)
    assert isinstance(cam, NoCamera) and cam.read(0.01) is None
    cam.close()
    cam.close()


def test_sim_frames_on_the_phase_grid_with_matching_detections():
    cfg = config.from_dict({"vehicle": {"role": "cav"}, "sim": {"rate_hz": 20.0, "phase_s": 0.01, "mode": "easy"}})
    radar = SimRadar(cfg)
    cam = SimCamera(cfg, radar=radar)
    assert radar.view == "cav"
    frames = []
    t0 = time.monotonic()
    while len(frames) < 6 and time.monotonic() - t0 < 10:
        f = radar.read(0.2)
        if f is not None:
            frames.append((f, time.time()))
    stamps = np.array([f.stamp for f, _ in frames])
    # consecutive grid frames; a frame the machine made late is skipped and counted, never shifted
    steps = np.diff(stamps) / 0.05
    assert np.allclose(steps, np.round(steps), atol=1e-4) and (np.round(steps) >= 1).all()
    assert int((np.round(steps) > 1).sum()) <= radar.counters()["late_skips"] <= 1
    assert np.allclose((stamps - 0.01) / 0.05, np.round((stamps - 0.01) / 0.05), atol=1e-6)
    # delivered at (not long after) its capture time
    assert all(-0.002 <= t - f.stamp < 0.5 for f, t in frames)
    det = cam.read(0.1)
    assert det is not None and det.stamp in set(stamps) and det.boxes.shape[1] == 6
    assert det.features.shape == (len(det.boxes), 32)
    assert cam.camera.K.shape == (3, 3)
    radar.close()
    cam.close()


def test_both_vehicles_see_the_same_world():
    c_cav = config.from_dict({"vehicle": {"role": "cav"}, "sim": {"mode": "easy"}})
    c_ego = config.from_dict({"vehicle": {"role": "ego"}, "sim": {"mode": "easy"}})
    a, b = SimRadar(c_cav), SimRadar(c_ego)
    t = 1000.0
    oa, ob = a.scenario.observe("cav", t), b.scenario.observe("cav", t)
    np.testing.assert_array_equal(oa.points, ob.points)  # same seed, same time -> same world
    assert not np.array_equal(a.scenario.observe("cav", t).world_T_radar, b.scenario.observe("ego", t).world_T_radar)


class FlakyCamera(NoCamera):
    """A camera that is unplugged after 3 frames and back after a while."""

    def __init__(self):
        super().__init__()
        self.n = 0
        self.gone_until = 0.0

    def read(self, timeout):
        from mmatch.errors import DeviceError
        from mmatch.types import Detections

        self.n += 1
        time.sleep(0.01)
        if 3 <= self.n < 6:
            raise DeviceError("camera gone")
        return Detections(np.zeros((0, 6), np.float32), np.zeros((0, 32), np.float32), time.time())


def test_camera_gone_is_counted_and_recovered():
    stop = threading.Event()
    got = []
    r = SensorReader("camera", FlakyCamera(), got.append, stop, reconnect_s=0.02)
    r.start()
    deadline = time.monotonic() + 5
    while len(got) < 6 and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    r.join(5)
    assert len(got) >= 6 and r.errors == 3 and r.reopens == 3


DCA_CFG = """\
sensorStop
flushCfg
dfeDataOutputMode 1
channelCfg 15 7 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 2 2 14 0 0 29 1 64 22000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 2
chirpCfg 2 2 0 0 0 0 0 4
frameCfg 0 2 16 0 50 1 0
lowPower 0 0
cfarCfg -1 0 2 8 4 3 0 15 1
cfarCfg -1 1 0 4 2 3 1 15 1
lvdsStreamCfg -1 0 1 0
sensorStart
"""


def test_dca1000_source_against_the_fake_fpga(tmp_path):
    from mmatch.drivers.dca1000.fake import FakeDca1000
    from mmatch.drivers.dca1000.layout import cube_to_raw
    from mmatch.drivers.dca1000.synth import Target, synth_cube
    from mmatch.drivers.ti.cfg import parse_cfg

    (tmp_path / "r.cfg").write_text(DCA_CFG)
    data_port = free_port(socket.SOCK_DGRAM)
    rcfg = parse_cfg(DCA_CFG)
    cfg = config.from_dict({"radar": {"source": "dca1000", "cfg": str(tmp_path / "r.cfg"), "dca_host": "127.0.0.1",
                                      "dca_fpga_host": "127.0.0.1", "dca_data_port": data_port,
                                      "dca_local_config_port": 0, "dca_config_port": 1},
                            "loop": {"queue_size": 16}})
    src = open_radar(cfg)
    raw = cube_to_raw(synth_cube(rcfg.chirp, src.geom, [Target(10.0, 0.0, 0.0)]), src.geom)
    with FakeDca1000(raw, src.geom.frame_bytes, 5, ("127.0.0.1", data_port), control_port=0,
                     rate_mb_s=20.0) as fake:
        port = fake.control_address[1]
        object.__setattr__(cfg.radar, "dca_config_port", port)
        raws = []
        src.raw_sink = raws.append
        src.open()
        frames = []
        deadline = time.monotonic() + 10
        while len(frames) < 3 and time.monotonic() < deadline:
            f = src.read(0.2)
            if f is not None:
                frames.append(f)
        src.close()
        src.close()
    assert len(frames) >= 3
    rng = np.hypot(frames[0].points[:, 0], frames[0].points[:, 1])
    assert np.any(np.abs(rng - 10.0) < 0.5), rng
    assert raws and len(raws[0]) == src.geom.frame_bytes


def test_camera_history_picks_closest_and_waits_for_a_late_image():
    from mmatch.edge.loop import CameraHistory
    from mmatch.types import Detections

    def det(t):
        return Detections(np.zeros((0, 6), np.float32), np.zeros((0, 32), np.float32), t)

    h = CameraHistory()
    for t in (1.00, 1.05, 1.10):
        h.put(det(t))
    assert h.closest(1.06, 0.1).stamp == 1.05
    assert h.closest(1.50, 0.1) is None  # nothing within tolerance
    threading.Timer(0.05, h.put, args=(det(1.20),)).start()
    t0 = time.monotonic()
    got = h.closest(1.20, 0.1, wait_s=2.0)  # the image of this radar frame lands a bit later
    assert got.stamp == 1.20 and time.monotonic() - t0 < 1.5


def test_edge_bench_quick_numbers():
    from mmatch.edge.bench import run

    out = run(quick=True)
    assert out["recorder_frames_per_s"] > 20 and out["reader_messages_per_s"] > 40
    assert 0 < out["zenoh_rtt_ms_median"] < 1000 and out["zenoh_rtt_lost"] == 0
    assert 0 < out["auth_sign_verify_ms_median"] < 50 and out["auth_forged_refused_per_s"] > 10


def _sim_radar_on_a_fake_clock(cfg, start: float) -> SimRadar:
    """A SimRadar whose clock starts at `start` and advances only by its own sleeps."""
    now = [start]
    return SimRadar(cfg, clock=lambda: now[0], sleep=lambda dt: now.__setitem__(0, now[0] + dt))


def test_sim_vehicle_clock_offset_shifts_stamps_not_the_world():
    seen = []
    cfg = config.from_dict({"vehicle": {"role": "cav"}, "sim": {"clock_offset_s": 0.3, "mode": "easy",
                                                                  "render_process": False}})
    radar = _sim_radar_on_a_fake_clock(cfg, 5000.0)
    real = radar.scenario.observe
    radar.scenario.observe = lambda view, t: (seen.append(t), real(view, t))[1]
    f = None
    while f is None:
        f = radar.read(0.2)
    assert f.stamp == pytest.approx(seen[0] + 0.3)  # own clock runs 0.3 s ahead of true time
    assert f.stamp == pytest.approx(round(f.stamp / 0.05) * 0.05)  # on its own 20 Hz grid


def test_render_process_gives_the_in_process_frames_and_falls_back_when_it_dies():
    """The child renders exactly what the vehicle's own process would; killed, the sensor
    renders itself from the next frame on (counted), without losing a frame."""
    from mmatch.sim.scenario import make_scenario

    cfg = config.from_dict({"vehicle": {"role": "ego"}, "sim": {"mode": "easy", "seed": 3}})
    radar = _sim_radar_on_a_fake_clock(cfg, 7000.0)
    assert radar._renderer is not None
    here = make_scenario(3, "easy", covisible=cfg.sim.covisible)
    got = [radar.read(1.0) for _ in range(3)]
    for f in got:
        want = here.observe("ego", f.stamp)
        assert np.array_equal(f.points, want.points)
    radar._renderer._proc.kill()
    radar._renderer._proc.wait()
    after = [radar.read(1.0) for _ in range(2)]
    assert all(f is not None for f in after)
    assert np.array_equal(after[0].points, here.observe("ego", after[0].stamp).points)
    assert radar.counters()["render_fallbacks"] == 1
    radar.close()
    radar.close()


def test_sim_sensor_renders_itself_when_no_render_process_can_start(monkeypatch):
    import mmatch.sim.renderd as renderd

    monkeypatch.setattr(renderd.sys, "executable", "/nonexistent/python")
    cfg = config.from_dict({"vehicle": {"role": "cav"}, "sim": {"mode": "easy"}})
    radar = _sim_radar_on_a_fake_clock(cfg, 9000.0)
    assert radar._renderer is None and radar.counters()["render_fallbacks"] == 1
    assert radar.read(1.0) is not None
    radar.close()
