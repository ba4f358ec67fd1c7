"""Replay: pacing, and a recorded log as the radar + camera sources of `mmatch run`."""

from __future__ import annotations

import json
import time

import numpy as np
from edge_proc import mmatch, write_vehicle_cfg

from mmatch.edge import logreader
from mmatch.edge.replay import Pacer, compare_fused, log_events


def test_pacer_keeps_recorded_time_and_speed():
    slept = []
    p = Pacer(fast=False, speed=2.0, sleep=slept.append)
    p.wait(0)
    p.wait(1_000_000_000)  # 1 s later in the log -> 0.5 s at speed 2
    assert len(slept) == 1 and 0.4 < slept[0] <= 0.5
    fast = Pacer(fast=True, sleep=slept.append)
    fast.wait(0)
    fast.wait(10**12)
    assert len(slept) == 1


def test_compare_fused_ignores_wall_clock_fields_only():
    a = [{"seq": 1, "stamp": 5.0, "status": "fused", "objects": [[1.0, 2.0, 0, 0]], "latency_ms": 3.0, "timings_ms": {"x": 1}}]
    b = [{"seq": 1, "stamp": 5.0, "status": "fused", "objects": [[1.0, 2.0, 0, 0]], "latency_ms": 9.0, "timings_ms": {"x": 5}}]
    assert compare_fused(a, b)["same"] == 1
    b[0]["objects"][0][0] = 1.01
    assert compare_fused(a, b)["differ"] == [1]
    assert compare_fused(a, [])["missing"] == [1]
    b[0]["objects"][0][0] = 1.0
    b[0]["stamp"] = 6.0  # same seq from another run of the service is another result
    assert compare_fused(a, b)["missing"] == [1]


def test_a_log_is_a_source_for_mmatch_run(tmp_path):
    # 1. record simulated sensors only
    rec_cfg = write_vehicle_cfg(tmp_path / "rec.toml", vid="cav1", role="cav", listen=[], connect=[],
                                log_dir=tmp_path / "rec")
    res = mmatch(["record", "-c", str(rec_cfg), "--duration", "3"])
    assert res.returncode == 0, res.stderr[-2000:]
    recorded = [e.frame for e in log_events(tmp_path / "rec") if e.kind == "frame"]
    assert len(recorded) >= 20
    # 2. the log drives a CAV run through the live loop, as fast as possible, then it stops
    run_cfg = write_vehicle_cfg(tmp_path / "run.toml", vid="cav1", role="cav", listen=[], connect=[],
                                log_dir=tmp_path / "run",
                                extra="")
    t0 = time.monotonic()
    res = mmatch(["run", "-c", str(run_cfg), "--set", "radar.source=\"replay\"",
                  "--set", f"radar.path=\"{tmp_path / 'rec'}\"", "--set", "radar.pace=\"fast\"",
                  "--set", "camera.source=\"replay\"", "--set", f"camera.path=\"{tmp_path / 'rec'}\""])
    assert res.returncode == 0, res.stderr[-2000:]
    assert time.monotonic() - t0 < 30
    replayed = [e.frame for e in log_events(tmp_path / "run") if e.kind == "frame"]
    assert [f.stamp for f in replayed] == [f.stamp for f in recorded]  # lossless, in order
    for a, b in zip(recorded, replayed):
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.boxes, b.boxes)
    tx = [m for m in logreader.read_messages(tmp_path / "run") if m.topic == "/shared/tx"]
    assert len(tx) == len(recorded)
    summary = json.loads(mmatch(["replay", str(tmp_path / "run"), "--fast"]).stdout)
    assert summary["frames"] == len(recorded)


def test_a_folder_with_two_runs_replays_each_from_a_fresh_state(tmp_path):
    cfg = write_vehicle_cfg(tmp_path / "cav.toml", vid="cav1", role="cav", listen=[], connect=[],
                            log_dir=tmp_path / "logs")
    for _ in range(2):  # the service restarted: a second run logs into the same folder
        res = mmatch(["run", "-c", str(cfg), "--duration", "1.5"])
        assert res.returncode == 0, res.stderr[-2000:]
    files = sorted(p.name for p in (tmp_path / "logs").glob("*.mcap"))
    assert len(files) == 2 and all(f.endswith("-0000.mcap") for f in files)
    tx = sum(1 for m in logreader.read_messages(tmp_path / "logs") if m.topic == "/shared/tx")
    summary = json.loads(mmatch(["replay", str(tmp_path / "logs"), "--fast"]).stdout)
    assert summary["runs"] == 2 and summary["frames"] == tx >= 20
