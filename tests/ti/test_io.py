"""Byte sources (loop://, pty, capture files fast and paced) and the CLI config sender
against a simulated radar on a pty."""

from __future__ import annotations

import os
import threading
import time
import tty
from pathlib import Path

import pytest
import serial

from mmatch.drivers.ti.cfg import load_cfg, parse_cfg
from mmatch.drivers.ti.config_sender import RadarConfigError, send_cfg
from mmatch.drivers.ti.reader import TlvReader
from mmatch.drivers.ti.sources import BytesSource, FileSource, SerialSource, open_source
from mmatch.drivers.ti.writer import encode_frame
from mmatch.errors import ConfigError, DeviceError, DeviceTimeout

from .helpers import make_points

REPO = Path(__file__).resolve().parents[2]


def stream_of(frame_numbers, fmt="sdk3", junk=b""):
    return junk + b"".join(encode_frame(make_points(5 + fn % 7, seed=fn), fn, fmt) for fn in frame_numbers)


@pytest.fixture
def pty_pair():
    """(master fd playing the device, path of the slave tty); both closed afterwards."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    path = os.ttyname(slave)
    yield master, path
    os.close(master)
    os.close(slave)


def test_loop_url_carries_a_stream():
    data = stream_of(range(1, 6), junk=b"\xff" * 50)
    with SerialSource("loop://", timeout=0.05) as src:
        src.write(data)
        reader = TlvReader(src, on_error="skip")
        frames = [reader.read_frame(timeout=2.0) for _ in range(5)]
        assert reader.read_frame(timeout=0.1) is None  # live: nothing more, no end
    assert [f.frame_number for f in frames] == [1, 2, 3, 4, 5]
    assert reader.stats.bytes_skipped == 50
    assert src.serial is None
    src.close()  # safe twice


def test_pty_data_port_921600(pty_pair):
    master, path = pty_pair
    data = stream_of(range(10, 40), fmt="pc3d", junk=b"\x02\x01\x04" * 100)
    with SerialSource(path, baudrate=921600, timeout=0.05) as src:
        assert src.serial.baudrate == 921600
        writer = threading.Thread(target=lambda: [os.write(master, data[k:k + 997])
                                                  for k in range(0, len(data), 997)])
        writer.start()
        reader = TlvReader(src, on_error="skip")
        got = []
        deadline = time.monotonic() + 10
        while len(got) < 30 and time.monotonic() < deadline:
            f = reader.read_frame(timeout=0.5)
            if f is not None:
                got.append(f)
        writer.join()
    assert [f.frame_number for f in got] == list(range(10, 40))
    assert all(f.points.shape[1] == 5 and f.host_time > 0 for f in got)
    assert reader.stats.bytes_skipped == 300


def test_serial_open_failure_is_device_error(tmp_path):
    with pytest.raises(DeviceError):
        SerialSource(str(tmp_path / "no-such-tty"))


def test_file_replay_fast(tmp_path):
    data = stream_of(range(1, 51), junk=b"junk" * 70)
    p = tmp_path / "cap.bin"
    p.write_bytes(data)
    with open_source(str(p)) as src:
        assert isinstance(src, FileSource)
        frames = list(TlvReader(src).frames())
    assert [f.frame_number for f in frames] == list(range(1, 51))
    assert src.eof


def test_file_replay_paced_by_frame_numbers(tmp_path):
    # frames 1..5, then a sensor restart at 1..3; fake clock records the due times
    data = stream_of([1, 2, 3, 4, 5, 1, 2, 3], junk=b"x" * 10)
    p = tmp_path / "cap.bin"
    p.write_bytes(data)
    now = [100.0]
    sleeps = []

    def sleep(dt):
        sleeps.append(dt)
        now[0] += dt

    src = FileSource(p, pace="frames", frame_period_s=0.1, speed=2.0, chunk=64, sleep=sleep,
                     clock=lambda: now[0])
    with src:
        frames = list(TlvReader(src).frames())
    assert [f.frame_number for f in frames] == [1, 2, 3, 4, 5, 1, 2, 3]
    # 0.1 s period at speed 2 -> 0.05 s apart; the restart continues one period later
    assert sleeps == pytest.approx([0.05] * 7)
    assert now[0] == pytest.approx(100.35)


def test_file_replay_paced_real_time(tmp_path):
    p = tmp_path / "cap.bin"
    p.write_bytes(stream_of(range(1, 5)))
    t0 = time.monotonic()
    with open_source(f"file:{p}?pace=frames&period=0.05") as src:
        n = sum(1 for _ in TlvReader(src).frames())
    dt = time.monotonic() - t0
    assert n == 4 and 0.14 <= dt < 2.0  # 3 gaps of 50 ms (generous upper bound)


def test_file_replay_baud_pace(tmp_path):
    data = stream_of(range(1, 4))
    p = tmp_path / "cap.bin"
    p.write_bytes(data)
    now = [0.0]

    def sleep(dt):
        now[0] += dt

    with FileSource(p, pace="baud", baudrate=115200, sleep=sleep, clock=lambda: now[0]) as src:
        assert len(list(TlvReader(src).frames())) == 3
    assert now[0] == pytest.approx(len(data) / 11520.0, rel=1e-6)


def test_open_source_rejects_bad_options(tmp_path):
    p = tmp_path / "cap.bin"
    p.write_bytes(b"")
    with pytest.raises(ConfigError):
        open_source(f"file:{p}?pace=warp")
    with pytest.raises(ConfigError):
        open_source(f"file:{p}?colour=red")
    with pytest.raises(DeviceError):
        open_source(f"file:{tmp_path / 'missing.bin'}")


def test_bytes_source_and_empty_file(tmp_path):
    src = BytesSource(stream_of([7]), chunk=10)
    assert [f.frame_number for f in TlvReader(src).frames()] == [7]
    p = tmp_path / "empty.bin"
    p.write_bytes(b"")
    with FileSource(p) as f:
        assert f.eof and list(TlvReader(f).frames()) == []


# ---- CLI configuration against a simulated radar ----------------------------------------

class FakeRadar(threading.Thread):
    """Plays a TI CLI on the pty master: echo, then Done + prompt, or Error, prompt only,
    or silence, per command name."""

    def __init__(self, master: int, behaviour: dict[str, str] | None = None) -> None:
        super().__init__(daemon=True)
        self.master = master
        self.behaviour = behaviour or {}
        self.received: list[str] = []
        self.stop = threading.Event()

    def run(self) -> None:
        buf = b""
        os.set_blocking(self.master, False)
        while not self.stop.is_set():
            try:
                data = os.read(self.master, 4096)
            except BlockingIOError:
                time.sleep(0.002)
                continue
            except OSError:
                return
            buf += data
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                line = raw.decode().strip()
                self.received.append(line)
                mode = self.behaviour.get(line.split()[0], "done")
                if mode == "silent":
                    continue
                out = line + "\r\n"
                if mode == "done":
                    out += "Done\r\n\nmmwDemo:/>"
                elif mode == "ignored":
                    out += "Ignored: Sensor is already stopped\r\nDone\r\n\nmmwDemo:/>"
                elif mode == "prompt":
                    out += "mmwDemo:/>"
                elif mode == "error":
                    out += "Error -1\r\nmmwDemo:/>"
                elif mode == "unknown":
                    out += f"'{line.split()[0]}' is not recognized as a CLI command\r\nmmwDemo:/>"
                os.write(self.master, out.encode())


@pytest.fixture
def radar(pty_pair):
    master, path = pty_pair
    radars = []

    def start(behaviour=None):
        r = FakeRadar(master, behaviour)
        r.start()
        radars.append(r)
        return r, path

    yield start
    for r in radars:
        r.stop.set()
        r.join(2)


VEHICLE_CFG = REPO / "cfg" / "radar" / "xwr18xx_vehicle_100m.cfg"


def test_send_cfg_all_lines(radar):
    dev, path = radar({"sensorStop": "ignored", "lowPower": "prompt"})
    cfg = load_cfg(VEHICLE_CFG)
    replies = send_cfg(path, cfg, timeout_s=2.0)
    assert dev.received == cfg.lines()
    assert len(replies) == len(cfg.commands) and not any(r.line.startswith("%") for r in replies)
    assert replies[0].line == "sensorStop" and "Ignored" in replies[0].answer
    assert replies[-1].line == "sensorStart" and replies[-1].answer.endswith("mmwDemo:/>")
    assert replies[-1].lineno == cfg.commands[-1][0]


def test_send_cfg_error_names_the_line(radar):
    _, path = radar({"profileCfg": "error"})
    cfg = load_cfg(VEHICLE_CFG)
    lineno = next(n for n, c, _ in cfg.commands if c == "profileCfg")
    with serial.Serial(path, 115200, timeout=0.05) as ser:
        with pytest.raises(RadarConfigError, match=rf"xwr18xx_vehicle_100m.cfg:{lineno}: .*profileCfg.*Error -1"):
            send_cfg(ser, cfg, timeout_s=2.0)


def test_send_cfg_unrecognised_command(radar):
    _, path = radar({"cfarFovCfg": "unknown"})
    with pytest.raises(RadarConfigError, match="not recognized"):
        send_cfg(path, load_cfg(VEHICLE_CFG), timeout_s=2.0)


def test_send_cfg_timeout_names_the_line(radar):
    dev, path = radar({"frameCfg": "silent"})
    cfg = load_cfg(VEHICLE_CFG)
    lineno = next(n for n, c, _ in cfg.commands if c == "frameCfg")
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match=rf":{lineno}: no 'Done' or prompt within 0.3 s after 'frameCfg"):
        send_cfg(path, cfg, timeout_s=0.3)
    assert time.monotonic() - t0 < 10
    assert dev.received[-1].startswith("frameCfg")  # nothing sent after the silent line


def test_bad_cfg_refused_before_sending(radar, tmp_path):
    dev, path = radar()
    bad = tmp_path / "bad.cfg"
    bad.write_text(VEHICLE_CFG.read_text().replace("frameCfg 0 1 128 0 50 1 0", "frameCfg 0 1 128 0 1 1 0"))
    with pytest.raises(ConfigError, match=r"bad.cfg:\d+: frameCfg: .*longer than the frame period"):
        send_cfg(path, load_cfg(bad))
    time.sleep(0.05)
    assert dev.received == []


def test_parse_cfg_from_sender_lines_roundtrip():
    cfg = load_cfg(VEHICLE_CFG)
    again = parse_cfg("\n".join(cfg.lines()))
    assert again.chirp == cfg.chirp


def test_send_cfg_follows_baud_rate_command(radar):
    _, path = radar()
    cfg = parse_cfg(VEHICLE_CFG.read_text().replace("sensorStart", "baudRate 1250000\nsensorStart"))
    with serial.Serial(path, 115200, timeout=0.05) as ser:
        replies = send_cfg(ser, cfg, timeout_s=2.0)
        assert ser.baudrate == 1250000
    assert [r.line for r in replies][-2:] == ["baudRate 1250000", "sensorStart"]
