"""A TI mmWave EVM without hardware: the CLI port and the data port on two pseudo-terminals.

Like the two USB serial ports of a real board: send the .cfg to `cli_port` (it echoes each
line and answers ``Done`` and the ``mmwDemo:/>`` prompt; an unknown command gets "not
recognized", a wrong argument count ``Error -1``, and ``sensorStart`` of a cfg that
`parse_cfg` refuses ``Error -1``), then read TLV packets from `data_port`: one per frame
period of the cfg (divided by `speed`) with the points of ``points_fn(frame_number)``,
written with `mmatch.drivers.ti.writer.encode_frame` in format `fmt`. ``sensorStop`` stops the
stream; ``sensorStart`` resumes it (frame numbers keep counting, like the firmware).

A pty, like a UART, does not wait for a reader: bytes that do not fit (nobody reading)
are dropped and counted in `bytes_dropped`, which makes for realistic partial frames.

    with SimulatedRadar(points_fn, fmt="sdk3", speed=10) as radar:
        send_cfg(radar.cli_port, "cfg/radar/xwr18xx_vehicle_100m.cfg")
        reader = TlvReader(SerialSource(radar.data_port))
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
import tty
from collections.abc import Callable

import numpy as np

from mmatch.drivers.ti.cfg import KNOWN_COMMANDS, ChirpParams, check_command, parse_cfg
from mmatch.drivers.ti.writer import encode_frame
from mmatch.errors import ConfigError

log = logging.getLogger(__name__)

PROMPT = "mmwDemo:/>"
CPU_HZ = 200e6
"""timeCpuCycles rate of the simulated R4F (cycles per second)."""


def default_points(frame_number: int, frame_period_s: float = 0.05) -> np.ndarray:
    """A car approaching from 60 m at 10 m/s (4 points) and two static reflectors."""
    t = frame_number * frame_period_s
    y = 60.0 - (10.0 * t) % 55.0
    car = np.array([[-1.0, y, 0.5, -10.0, 25.0], [1.0, y, 0.5, -10.0, 24.0],
                    [-0.8, y + 0.5, 1.0, -10.0, 20.0], [0.8, y + 0.5, 1.0, -10.0, 19.0]], np.float32)
    static = np.array([[5.0, 20.0, 0.0, 0.0, 30.0], [-6.0, 35.0, 0.0, 0.0, 28.0]], np.float32)
    return np.vstack([car, static])


class _Pty:
    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)  # no echo, no line discipline until a client configures it
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class SimulatedRadar:
    """A simulated TI radar on two ptys (see module doc).

    points_fn: frame number -> float32 (N, 5) points (default: `default_points`).
    fmt: TLV format of the data port (a key of drivers.ti.writer.FORMATS).
    speed: frames come `speed` times faster than the cfg's frame period.
    """

    def __init__(self, points_fn: Callable[[int], np.ndarray] | None = None, fmt: str = "sdk3",
                 *, speed: float = 1.0, first_frame: int = 1) -> None:
        self.points_fn = points_fn
        self.fmt = fmt
        self.speed = speed
        self._cli = _Pty()
        self._data = _Pty()
        self.cli_port = self._cli.path
        self.data_port = self._data.path
        self.received: list[str] = []
        self.chirp: ChirpParams | None = None
        self.frames_sent = 0
        self.bytes_dropped = 0
        self._next_frame = first_frame
        self._streaming = threading.Event()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._cli_loop, name="sim-radar-cli", daemon=True),
                         threading.Thread(target=self._data_loop, name="sim-radar-data", daemon=True)]
        for t in self._threads:
            t.start()

    # ---- CLI port ----------------------------------------------------------------------
    def _answer(self, line: str) -> str:
        cmd = line.split()[0]
        if cmd not in KNOWN_COMMANDS:
            return f"'{cmd}' is not recognized as a CLI command\r\n"
        try:
            check_command(line)
        except ConfigError:
            return "Error -1\r\n"
        if cmd == "sensorStop":
            was = self._streaming.is_set()
            self._streaming.clear()
            return "Done\r\n" if was else "Ignored: Sensor is already stopped\r\nDone\r\n"
        if cmd == "flushCfg":
            self.received = []
            return "Done\r\n"
        if cmd == "sensorStart":
            try:
                self.chirp = parse_cfg("\n".join(self.received), "<cli>").chirp
            except ConfigError as exc:
                log.info("simulated radar refuses sensorStart: %s", exc)
                return "Error -1\r\n"
            self._streaming.set()
        return "Done\r\n"

    def _cli_loop(self) -> None:
        buf = b""
        fd = self._cli.master
        while not self._stop.is_set():
            r, _, _ = select.select([fd], [], [], 0.05)
            if not r:
                continue
            try:
                data = os.read(fd, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                return
            buf += data
            while True:
                cut = min((i for i in (buf.find(b"\n"), buf.find(b"\r")) if i >= 0), default=-1)
                if cut < 0:
                    break
                raw, buf = buf[:cut], buf[cut + 1:]
                line = raw.decode("ascii", errors="replace").strip()
                if not line:
                    continue
                self.received.append(line)
                answer = line + "\r\n" + self._answer(line) + "\n" + PROMPT
                self._write(fd, answer.encode("ascii"))

    # ---- data port ---------------------------------------------------------------------
    def _data_loop(self) -> None:
        due: float | None = None
        while not self._stop.is_set():
            if not self._streaming.wait(0.05):
                due = None
                continue
            chirp = self.chirp
            period = (chirp.frame_period_ms * 1e-3 if chirp else 0.05) / self.speed
            now = time.monotonic()
            due = now if due is None else due + period
            if due > now:
                self._stop.wait(due - now)
                if self._stop.is_set() or not self._streaming.is_set():
                    continue
            fn = self._next_frame
            self._next_frame += 1
            pts = self.points_fn(fn) if self.points_fn else default_points(fn, period * self.speed)
            cycles = int(fn * period * self.speed * CPU_HZ) & 0xFFFFFFFF
            packet = encode_frame(pts, fn, self.fmt, chirp=chirp, time_cpu_cycles=cycles)
            self._write(self._data.master, packet)
            self.frames_sent += 1

    def _write(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:  # nobody reading: the rest is lost, as on a UART
                self.bytes_dropped += len(view)
                return
            except OSError:
                return
            view = view[n:]

    # ---- lifetime ----------------------------------------------------------------------
    @property
    def streaming(self) -> bool:
        return self._streaming.is_set()

    def close(self) -> None:
        """Stop both ports (safe twice)."""
        if self._stop.is_set():
            return
        self._stop.set()
        for t in self._threads:
            t.join(2.0)
        self._cli.close()
        self._data.close()

    def __enter__(self) -> SimulatedRadar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

