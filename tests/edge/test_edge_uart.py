"""The UART radar source over a pty at 921600 baud: done-when equality with `mmatch replay`
of the raw capture, unplug/replug recovery, garbage counted."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest
from edge_proc import mmatch, start, stop, wait_for

from mmatch.drivers.ti.writer import encode_frame
from mmatch.edge import config, logschema
from mmatch.edge.loop import SensorReader
from mmatch.edge.logreader import read_messages
from mmatch.edge.replay import log_events
from mmatch.edge.sources.uart import UartRadar

BAUD = 921600


def _points(rng: np.random.Generator, n: int) -> np.ndarray:
    p = np.zeros((n, 5), np.float32)
    r, az = rng.uniform(2, 60, n), rng.uniform(-1, 1, n)
    p[:, 0], p[:, 1] = r * np.sin(az), r * np.cos(az)
    p[:, 2] = rng.uniform(-1, 1, n)
    p[:, 3] = rng.uniform(-20, 20, n)
    p[:, 4] = rng.uniform(5, 35, n)
    return p


def make_capture(n: int = 40, seed: int = 3) -> tuple[bytes, list[int]]:
    """A raw data-port capture: leading junk, junk and a cut frame inside, a truncated end.
    Returns the bytes and the frame numbers a correct reader accepts."""
    rng = np.random.default_rng(seed)
    out = [rng.integers(0, 256, 300, dtype=np.uint8).tobytes()]  # starts mid-stream
    good = []
    for k in range(n):
        fn = 100 + k
        frame = encode_frame(_points(rng, int(rng.integers(0, 30))), fn, "sdk3")
        if k == 10:
            out.append(frame[: len(frame) // 2])  # bytes lost: this frame is cut
            continue
        if k % 7 == 3:
            out.append(rng.integers(0, 256, 50, dtype=np.uint8).tobytes())  # line noise
        out.append(frame)
        good.append(fn)
    out.append(encode_frame(_points(rng, 12), 100 + n, "sdk3")[:-40])  # recording stopped mid-frame
    return b"".join(out), good


class Pty:
    """A pty whose master plays the radar's data port."""

    def __init__(self, link: Path | None = None) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self.link = link
        if link is not None:
            link.symlink_to(self.path)

    def write_paced(self, data: bytes, baud: int = BAUD, chunk: int = 256) -> None:
        t0 = time.monotonic()
        for i in range(0, len(data), chunk):
            os.write(self.master, data[i:i + chunk])
            due = t0 + (i + chunk) * 10 / baud
            if due > time.monotonic():
                time.sleep(due - time.monotonic())

    def unplug(self) -> None:
        if self.link is not None:
            self.link.unlink()
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


def _uart_cfg(path: Path, port: str, log_dir: Path | None = None) -> Path:
    path.write_text(f"""
[vehicle]
id = "rec1"
role = "cav"
[radar]
source = "uart"
port = "{port}"
baudrate = {BAUD}
reconnect_s = 0.1
[camera]
source = "none"
[auth]
keys = "dev"
dev_dir = "{path.parent / 'dev-keys'}"
[log]
dir = "{log_dir or ''}"
flush_s = 0.2
raw_floor_mb = 0
floor_mb = 0
""")
    return path


@pytest.mark.slow
def test_raw_capture_replay_equals_the_streaming_reader_over_a_pty(tmp_path):
    data, good = make_capture()
    cap = tmp_path / "capture.bin"
    cap.write_bytes(data)
    port = Pty()
    logs = tmp_path / "logs"
    cfg = _uart_cfg(tmp_path / "rec.toml", port.path, logs)
    proc = start(["record", "-c", str(cfg)], tmp_path / "record.out", nice=False)
    try:
        assert wait_for(lambda: "radar uart open" in (tmp_path / "record.out").read_text(), 30), \
            (tmp_path / "record.out").read_text()
        port.write_paced(data)  # at the line rate of 921600 baud
        time.sleep(1.0)
        assert stop(proc, signal.SIGTERM) == 0
    finally:
        stop(proc, signal.SIGKILL)
        port.unplug()
    live = [e.frame for e in log_events(logs) if e.kind == "frame"]
    raw = b"".join(m.data for m in read_messages(logs, topics=[logschema.RAW_UART]))
    assert raw == data  # the field log holds every byte of the port
    assert [f.frame_number for f in live] == good

    res = mmatch(["replay", str(cap), "--fast", "--no-process", "--frames-out", str(tmp_path / "f.json")])
    assert res.returncode == 0, res.stderr
    rep = json.loads((tmp_path / "f.json").read_text())
    assert rep["frame_numbers"] == good
    for f, pts in zip(live, rep["points"]):
        np.testing.assert_array_equal(np.asarray(pts, np.float32).reshape(-1, 5), f.points)
    summary = json.loads(res.stdout)
    assert summary["reader"]["bytes_skipped"] > 300 and summary["reader"]["frames"] == len(good)


def test_unplug_and_replug_recover_without_restart(tmp_path):
    link = tmp_path / "ttyRADAR"
    port = Pty(link)
    cfg = config.load(_uart_cfg(tmp_path / "u.toml", str(link)))
    src = UartRadar(cfg)
    frames: list = []
    raw: list[bytes] = []
    src.raw_sink = raw.append
    stop_ev = threading.Event()
    reader = SensorReader("radar", src, frames.append, stop_ev, reconnect_s=0.05, timeout=0.1)
    reader.start()
    rng = np.random.default_rng(1)
    try:
        assert wait_for(lambda: reader.opened, 5)
        port.write_paced(b"\xff" * 64 + encode_frame(_points(rng, 5), 1) + encode_frame(_points(rng, 5), 2))
        assert wait_for(lambda: len(frames) == 2, 5)
        port.unplug()  # the USB cable is pulled
        assert wait_for(lambda: reader.errors >= 1, 5)
        time.sleep(0.3)  # reopen attempts fail while the device is gone
        port = Pty(link)  # plugged back in (a new tty behind the same name)
        assert wait_for(lambda: reader.opened, 5)
        port.write_paced(encode_frame(_points(rng, 7), 3) + encode_frame(_points(rng, 7), 4))
        assert wait_for(lambda: len(frames) == 4, 5)
    finally:
        stop_ev.set()
        reader.join(5)
        port.unplug()
    assert [f.frame_number for f in frames] == [1, 2, 3, 4]
    assert reader.errors >= 1 and reader.reopens >= 1
    assert b"".join(raw).startswith(b"\xff" * 64)


def test_garbage_is_counted_not_raised(tmp_path):
    from edge_proc import open_fds

    before = open_fds()
    port = Pty()
    cfg = config.load(_uart_cfg(tmp_path / "g.toml", port.path))
    rng = np.random.default_rng(2)
    with UartRadar(cfg) as src:
        port.write_paced(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes()
                         + encode_frame(_points(rng, 4), 9))
        got = None
        deadline = time.monotonic() + 5
        while got is None and time.monotonic() < deadline:
            got = src.read(0.2)
        c = src.counters()
    port.unplug()
    assert open_fds() == before  # the source closed its port
    assert got is not None and got.frame_number == 9
    assert c["bytes_skipped"] >= 5000 and c["frames"] == 1


@pytest.mark.slow
def test_run_configures_a_simulated_evm_and_streams_its_frames(tmp_path):
    from mmatch.drivers.ti.simulator import SimulatedRadar, default_points

    profile = Path(__file__).resolve().parents[2] / "cfg" / "radar" / "xwr18xx_vehicle_100m.cfg"
    with SimulatedRadar(fmt="sdk3") as evm:
        cfg = _uart_cfg(tmp_path / "evm.toml", evm.data_port, tmp_path / "logs")
        text = cfg.read_text().replace('reconnect_s = 0.1', f'reconnect_s = 0.1\ncli_port = "{evm.cli_port}"\n'
                                                           f'cfg = "{profile}"')
        cfg.write_text(text)
        res = mmatch(["run", "-c", str(cfg), "--duration", "4"], timeout=60)
        assert res.returncode == 0, res.stderr[-3000:]
        assert any(line.startswith("sensorStart") for line in evm.received)
    frames = [e.frame for e in log_events(tmp_path / "logs") if e.kind == "frame"]
    assert len(frames) >= 10
    fns = [f.frame_number for f in frames]
    assert fns == sorted(fns)
    np.testing.assert_allclose(frames[-1].points[:, :4], default_points(fns[-1])[:, :4], atol=1e-5)
