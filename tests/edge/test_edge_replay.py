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


def test_compare_matches_only_when_nothing_differs_is_missing_or_extra():
    a = [{"seq": k, "stamp": 5.0 + 0.05 * k, "status": "fused"} for k in range(1, 4)]
    assert compare_fused(a, [dict(m) for m in a])["match"]
    assert not compare_fused(a, a[:2])["match"]                                   # missing
    extra = [*a, {"seq": 9, "stamp": 5.06, "status": "fused"}]
    assert compare_fused(a, extra)["extra"] == [9] and not compare_fused(a, extra)["match"]
    late = [*a, {"seq": 4, "stamp": 9.0, "status": "fused"}]                      # after the last record
    assert compare_fused(a, late)["match"]
    assert not compare_fused([], [])["match"]                                     # nothing to compare


def _corrupt_a_chunk(path, which: int, length_field: bool = False) -> int:
    """Flip a byte inside the `which`-th chunk record's data (or its length); returns the offset."""
    import struct as _struct

    data = bytearray(path.read_bytes())
    at, k = 8, 0
    while at < len(data):
        opcode, length = _struct.unpack_from("<BQ", data, at)
        if opcode == 0x06:
            if k == which:
                if length_field:
                    data[at + 8] ^= 0x7F        # the top byte of the length: far past the end
                else:
                    data[at + 9 + length - 10] ^= 0xFF
                path.write_bytes(bytes(data))
                return at
            k += 1
        at += 9 + length
    raise AssertionError("not that many chunks")


def test_a_corrupt_chunk_costs_that_chunk_and_reading_goes_on(tmp_path):
    from mmatch.edge import logschema
    from mmatch.edge.config import LogSection
    from mmatch.edge.recorder import Recorder

    with Recorder(LogSection(dir=str(tmp_path / "logs"), chunk_kb=1.0, raw_floor_mb=0.0, floor_mb=0.0)) as rec:
        for i in range(200):
            rec.write(logschema.FUSED, {"i": i, "pad": "p" * 100})
    path = rec.files[0]
    full = [json.loads(m.data)["i"] for m in logreader.read_messages(path)]
    assert full == list(range(200))
    for length_field in (False, True):
        bad = tmp_path / f"bad-{length_field}.mcap"
        bad.write_bytes(path.read_bytes())
        _corrupt_a_chunk(bad, 3, length_field)
        report = logreader.LogReport()
        got = [json.loads(m.data)["i"] for m in logreader.read_messages(bad, report=report)]
        assert report.corrupt, report
        assert got == sorted(got) and got[-1] == 199           # it went on to the end
        assert 150 <= len(got) < 200 and got[:5] == [0, 1, 2, 3, 4]  # one chunk's worth lost


def test_replay_of_a_damaged_log_goes_on_and_a_non_log_is_a_clear_error(tmp_path):
    cfg = write_vehicle_cfg(tmp_path / "cav.toml", vid="cav1", role="cav", listen=[], connect=[],
                            log_dir=tmp_path / "logs", extra="")
    cfg.write_text(cfg.read_text().replace("chunk_kb = 64", "chunk_kb = 4"))
    assert mmatch(["run", "-c", str(cfg), "--duration", "2.5"]).returncode == 0
    (log_file,) = (tmp_path / "logs").glob("*.mcap")
    clean = json.loads(mmatch(["replay", str(log_file), "--fast"]).stdout)
    n_clean = sum(1 for _ in logreader.read_messages(log_file))
    _corrupt_a_chunk(log_file, 2)
    res = mmatch(["replay", str(log_file), "--fast"])
    damaged = json.loads(res.stdout)
    assert res.returncode == 0 and damaged["corrupt"] and damaged["truncated"] == []
    assert 0.5 * clean["frames"] < damaged["frames"] <= clean["frames"]   # the rest replayed
    assert sum(1 for _ in logreader.read_messages(log_file)) < n_clean
    res = mmatch(["replay", str(log_file), "--fast", "--compare"])   # a CAV log: no results to compare
    assert res.returncode == 1
    for name, content in (("notes.txt", b"just some text\n" * 100), ("empty.bin", b"")):
        (tmp_path / name).write_bytes(content)
        res = mmatch(["replay", str(tmp_path / name), "--fast"])
        assert res.returncode == 2 and "neither an MCAP log nor a raw TI UART capture" in res.stderr
        assert str(tmp_path / name) in res.stderr and "Traceback" not in res.stderr
