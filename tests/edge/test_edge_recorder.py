"""MCAP recorder: chunked writing, rotation, disk floor, SIGKILL survival, replay up to a break."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from mmatch.edge import logreader, logschema
from mmatch.edge.config import LogSection
from mmatch.edge.recorder import MB, Recorder
from mmatch.errors import ParseError

REPO = Path(__file__).resolve().parents[2]


def _cfg(tmp_path, **kw) -> LogSection:
    base = dict(dir=str(tmp_path / "logs"), chunk_kb=4.0, flush_s=60.0, compression="zstd",
                raw_floor_mb=0.0, floor_mb=0.0)
    base.update(kw)
    return LogSection(**base)


def test_round_trip_all_topic_kinds(tmp_path):
    pts = np.random.default_rng(0).normal(size=(37, 5)).astype(np.float32)
    with Recorder(_cfg(tmp_path), config_text="[vehicle]\nid = \"t\"\n") as rec:
        assert rec.write(logschema.RAW_UART, b"\x02\x01\x04\x03\x06\x05\x08\x07abc")
        assert rec.write(logschema.POINTS, logschema.points_message(pts, 12.5, "t"), stamp=12.5)
        assert rec.write(logschema.SHARED_RX_PREFIX + "cav1", {"data": "d2lyZQ=="})
        assert rec.write(logschema.FUSED, {"seq": 1, "status": "fused"})
    report = logreader.LogReport()
    msgs = list(logreader.read_messages(rec.files[0], report=report))
    assert [m.topic for m in msgs] == ["/raw/uart", "/radar/points", "/shared/rx/cav1", "/fused"]
    assert report.truncated == [] and report.messages == 4
    assert any(k.endswith(":config") for k in report.metadata)
    back, stamp = logschema.points_from_message(msgs[1].data)
    np.testing.assert_array_equal(back, pts)
    assert stamp == pytest.approx(12.5)
    assert msgs[1].schema == "foxglove.PointCloud" and msgs[1].encoding == "protobuf"
    assert logschema.shared_payload(msgs[2].data, msgs[2].encoding) == b"wire"
    assert [m.log_time_ns for m in msgs] == sorted({m.log_time_ns for m in msgs})
    # the effective config is saved beside the log
    assert list((tmp_path / "logs").glob("*.config.toml"))


def test_foxglove_pointcloud_layout():
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    msg = PointCloud.FromString(logschema.points_message(np.ones((3, 5), np.float32), 1.25, "cav1"))
    assert msg.point_stride == 20 and (msg.timestamp.seconds, msg.timestamp.nanos) == (1, 250_000_000)
    assert msg.frame_id == "cav1/radar"
    assert [(f.name, f.offset, f.type) for f in msg.fields] == [
        ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("doppler", 12, 7), ("snr", 16, 7)]
    name, encoding, data, message_encoding = logschema.schema_for(logschema.POINTS)
    assert (name, encoding, message_encoding) == ("foxglove.PointCloud", "protobuf", "protobuf")
    assert b"foxglove/PointCloud.proto" in data


def test_rotation_by_size_and_time(tmp_path):
    with Recorder(_cfg(tmp_path, rotate_mb=0.05)) as rec:
        for _ in range(40):
            rec.write(logschema.RAW_UART, os.urandom(4000))
    assert len(rec.files) >= 3
    total = sum(1 for _ in logreader.read_messages(tmp_path / "logs"))
    assert total == 40
    clock = {"s": 100.0}  # the rotation's clock, so a slow writer thread cannot age the file
    with Recorder(_cfg(tmp_path / "b", rotate_s=0.05), monotonic=lambda: clock["s"]) as rec2:
        rec2.write(logschema.FUSED, {"a": 1})
        assert _wait(lambda: rec2.written == 1)
        clock["s"] += 0.04
        rec2.write(logschema.FUSED, {"a": 2})
        assert _wait(lambda: rec2.written == 2)
        assert len(rec2.files) == 1  # younger than rotate_s: no rotation
        clock["s"] += 0.02
        rec2.write(logschema.FUSED, {"a": 3})
    assert len(rec2.files) == 2
    assert [m.data for m in logreader.read_messages(rec2.files[1])] == [b'{"a":3}']


def test_disk_floor_stops_raw_first_then_everything(tmp_path):
    free = {"v": 10_000 * MB}
    rec = Recorder(_cfg(tmp_path, raw_floor_mb=1000.0, floor_mb=100.0), free_bytes=lambda p: free["v"])
    rec._last_disk_check = -1e9
    with rec:
        assert rec.write(logschema.RAW_UART, b"x")
        free["v"] = 500 * MB
        rec._last_disk_check = -1e9
        assert not rec.write(logschema.RAW_UART, b"x")
        assert rec.write(logschema.FUSED, {"still": True})
        assert rec.raw_stopped and not rec.all_stopped
        free["v"] = 50 * MB
        rec._last_disk_check = -1e9
        assert not rec.write(logschema.FUSED, {"no": 1})
        assert rec.all_stopped
        free["v"] = 10_000 * MB
        rec._last_disk_check = -1e9
        assert rec.write(logschema.RAW_UART, b"back")
    assert rec.dropped == {"raw_disk_floor": 1, "disk_floor": 1}
    topics = [m.topic for m in logreader.read_messages(tmp_path / "logs")]
    assert topics == ["/raw/uart", "/fused", "/raw/uart"]
    assert len(rec.files) == 2  # the floor closed the first file; a new one started on resume


def test_truncated_file_replays_up_to_the_break(tmp_path):
    with Recorder(_cfg(tmp_path, chunk_kb=1.0)) as rec:
        for i in range(50):
            rec.write(logschema.FUSED, {"i": i, "pad": "x" * 200})
    data = rec.files[0].read_bytes()
    full = [json.loads(m.data)["i"] for m in logreader.read_messages(rec.files[0])]
    assert full == list(range(50))
    cut = tmp_path / "cut.mcap"
    seen = []
    for size in (len(data) // 3, len(data) // 2, len(data) - 30):
        cut.write_bytes(data[:size])
        report = logreader.LogReport()
        got = [json.loads(m.data)["i"] for m in logreader.read_messages(cut, report=report)]
        assert got == list(range(len(got)))  # a prefix, in order
        assert report.truncated
        seen.append(len(got))
    assert 0 < seen[0] < seen[1] <= 50


def test_not_mcap_is_refused(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello")
    with pytest.raises(ParseError, match="not an MCAP"):
        list(logreader.read_messages(p))


WRITER = textwrap.dedent("""
    import sys, time
    from mmatch.edge.config import LogSection
    from mmatch.edge.recorder import Recorder
    from mmatch.edge import logschema
    rec = Recorder(LogSection(dir=sys.argv[1], chunk_kb=2.0, flush_s=0.05, compression="zstd",
                              raw_floor_mb=0.0, floor_mb=0.0)).open()
    i = 0
    while True:
        rec.write(logschema.FUSED, {"i": i, "pad": "y" * 100})
        i += 1
        if i % 20 == 0:
            print(i, flush=True)
        time.sleep(0.001)
""")


@pytest.mark.slow
def test_sigkilled_writer_leaves_a_readable_file(tmp_path):
    logs = tmp_path / "logs"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(logs)], cwd=REPO,
                            stdout=subprocess.PIPE, text=True)
    try:
        last = 0
        deadline = time.monotonic() + 30
        while last < 400 and time.monotonic() < deadline:
            last = int(proc.stdout.readline())
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        proc.stdout.close()
    assert last >= 400
    report = logreader.LogReport()
    got = [json.loads(m.data)["i"] for m in logreader.read_messages(logs, report=report)]
    assert report.truncated  # no footer: the reader met the break and said so
    assert got == list(range(len(got)))
    # at most the last chunk (<= ~2 KiB of ~150-byte messages) or flush interval is lost
    assert len(got) >= last - 40


def _wait(cond, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.01)
    return cond()


def test_disk_error_costs_the_file_then_recording_resumes_after_the_backoff(tmp_path, monkeypatch):
    from mmatch.edge import recorder as recmod

    with Recorder(_cfg(tmp_path, chunk_kb=1.0, retry_s=0.3)) as rec:
        for i in range(20):
            rec.write(logschema.FUSED, {"i": i, "pad": "z" * 100})
        assert _wait(lambda: rec.written >= 20)
        real_write = recmod._RawFile.write
        calls = {"n": 0}

        def failing_write(self, data):
            calls["n"] += 1
            if calls["n"] == 1:
                raise OSError(5, "Input/output error")
            return real_write(self, data)

        monkeypatch.setattr(recmod._RawFile, "write", failing_write)
        for i in range(20, 40):                      # the error, then the back-off drops
            rec.write(logschema.FUSED, {"i": i, "pad": "z" * 100})
        assert _wait(lambda: rec.failing) and rec.stats()["state"] == "failing"
        time.sleep(1.1)                              # the first back-off is 1 s (capped by retry_s)
        for i in range(40, 60):
            rec.write(logschema.FUSED, {"i": i, "pad": "z" * 100})
        assert _wait(lambda: not rec.failing)
    assert len(rec.files) == 2
    first, second = ([json.loads(m.data)["i"] for m in logreader.read_messages(f)] for f in rec.files)
    assert first == list(range(len(first))) and len(first) >= 5  # its complete chunks survive
    assert second[-1] == 59 and len(second) >= 15                 # recording went on in a new file
    lost = rec.dropped["disk_error"]
    assert lost >= 1 and len(first) + len(second) + lost == 60     # every message counted


def test_disk_full_mid_run_no_file_storm_one_error_then_resume(tmp_path, monkeypatch, caplog):
    """ENOSPC on every write for 2 s at 50 messages/s, retries every 0.3 s: no new files
    stay, one error line, every lost message counted; then space returns."""
    import errno
    import logging

    from mmatch.edge import recorder as recmod

    real_write = recmod._RawFile.write
    full = {"on": False}

    def write(self, data):
        if full["on"]:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(self, data)

    monkeypatch.setattr(recmod._RawFile, "write", write)
    caplog.set_level(logging.INFO, logger="mmatch.edge.recorder")
    logs = tmp_path / "logs"
    with Recorder(_cfg(tmp_path, chunk_kb=1.0, flush_s=0.1, retry_s=0.3, error_interval_s=30.0)) as rec:
        for i in range(20):
            rec.write(logschema.FUSED, {"i": i, "pad": "z" * 100})
        assert _wait(lambda: rec.written >= 20)
        full["on"] = True
        for i in range(20, 120):
            rec.write(logschema.FUSED, {"i": i, "pad": "z" * 100})
            time.sleep(0.02)
        assert rec.stats()["state"] == "failing" and "No space left" in rec.stats()["error"]
        files_while_full = {p.name for p in logs.glob("*.mcap")}
        full["on"] = False
        time.sleep(0.4)
        for i in range(120, 140):
            rec.write(logschema.FUSED, {"i": i, "pad": "z" * 100})
            time.sleep(0.02)
        assert _wait(lambda: rec.stats()["state"] == "recording")
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1, [r.getMessage() for r in errors]
    assert any("recording again" in r.getMessage() for r in caplog.records)
    assert len(files_while_full) == 1                  # only the file that was open when it filled
    # no retry left a file behind: the folder holds the file that filled and the one after it
    # (the retries' own files were counted while they lived once: timing-bound on a busy host)
    assert {p.name for p in logs.glob("*.mcap")} == {p.name for p in rec.files}
    got = [json.loads(m.data)["i"] for f in sorted(logs.glob("*.mcap")) for m in logreader.read_messages(f)]
    assert len(rec.files) == 2 and got[-1] == 139 and set(range(124, 140)) <= set(got)
    assert len(got) + rec.dropped["disk_error"] == 140


def test_an_unusable_log_folder_at_start_is_not_fatal_and_recording_starts_when_it_is_back(tmp_path):
    logs = tmp_path / "logs"
    logs.write_text("a file where the folder should be")     # mkdir fails, as on a dead disk
    with Recorder(_cfg(tmp_path, retry_s=0.3), config_text="x = 1\n") as rec:
        assert rec.stats()["state"] == "failing" and str(logs) in rec.stats()["error"]
        assert rec.write(logschema.FUSED, {"i": 0}) is False
        logs.unlink()
        time.sleep(1.1)
        for i in range(1, 11):
            rec.write(logschema.FUSED, {"i": i})
            time.sleep(0.01)
        assert _wait(lambda: rec.stats()["state"] == "recording")
    got = [json.loads(m.data)["i"] for m in logreader.read_messages(logs)]
    assert got and got[-1] == 10 and rec.dropped["disk_error"] >= 1


def test_deferred_records_keep_call_order_and_a_failing_one_costs_only_itself(tmp_path):
    import threading

    caller = threading.get_ident()
    seen: list[int] = []

    def build(i: int):  # noqa: ANN202
        seen.append(threading.get_ident())
        if i == 2:
            raise ValueError("broken encoder")
        return {"i": i}

    with Recorder(_cfg(tmp_path)) as rec:
        for i in range(4):
            assert rec.write(logschema.FUSED, lambda i=i: build(i))
        assert rec.write(logschema.HEALTH, {"eager": True})
    msgs = list(logreader.read_messages(rec.files[0]))
    assert [json.loads(m.data) for m in msgs] == [{"i": 0}, {"i": 1}, {"i": 3}, {"eager": True}]
    assert rec.dropped == {"encode_error": 1}
    assert caller not in seen and len(seen) == 4  # built on the writer thread
