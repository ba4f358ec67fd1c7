"""Byte sources for the TLV reader: serial port, capture-file replay, in-memory bytes.

Every source has ``read(max_bytes) -> bytes`` (b"" when nothing arrived within its timeout),
``eof`` (True once a finite source is exhausted), and ``close()`` (safe twice); each is a
context manager. `open_source` picks one from a string:

* ``"loop://"``, ``"socket://127.0.0.1:PORT"``, ``"/dev/ttyACM1"``, ``"COM4"`` -> `SerialSource`
  (pyserial; the TI data port runs at 921600 baud, the CLI port at 115200)
* ``"file:PATH"`` or an existing file path -> `FileSource` as fast as possible;
  ``"file:PATH?pace=frames&period=0.05&speed=1"`` at the recorded frame pace,
  ``"file:PATH?pace=baud&baud=921600"`` at the serial line's byte rate.

A raw capture holds no timestamps, so "recorded pace" means: each frame is released at
``t0 + (frameNumber - first) * period / speed`` (period from the cfg's frameCfg), rebased
when the frame number goes back (sensor restart) or jumps by more than `max_jump` frames.
"""

from __future__ import annotations

import logging
import os
import struct
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from urllib.parse import parse_qs

from mmatch.drivers.ti.header import MAGIC
from mmatch.errors import ConfigError, DeviceError

log = logging.getLogger(__name__)

DATA_BAUD = 921600
CLI_BAUD = 115200


class ByteSource(ABC):
    """A stream of bytes (see module doc)."""

    eof: bool = False

    @abstractmethod
    def read(self, max_bytes: int = 65536) -> bytes:
        """Up to `max_bytes` bytes; b"" if none arrived within the source's timeout."""

    def close(self) -> None:
        """Release the source (safe to call twice)."""

    def __enter__(self) -> ByteSource:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class BytesSource(ByteSource):
    """In-memory bytes, handed out in pieces of at most `chunk` bytes."""

    def __init__(self, data: bytes, chunk: int = 65536) -> None:
        self._data = bytes(data)
        self._pos = 0
        self._chunk = chunk
        self.eof = not self._data

    def read(self, max_bytes: int = 65536) -> bytes:
        n = min(max_bytes, self._chunk)
        out = self._data[self._pos:self._pos + n]
        self._pos += len(out)
        self.eof = self._pos >= len(self._data)
        return out


class SerialSource(ByteSource):
    """A pyserial port or URL (``loop://``, ``socket://``, a device path).

    timeout: seconds one `read` waits for the first byte. Never reaches `eof`.
    The port is opened here (not in a default argument) and closed by `close()`.
    """

    def __init__(self, port: str, baudrate: int = DATA_BAUD, timeout: float = 0.05,
                 serial_obj: object | None = None) -> None:
        import serial  # pyserial; imported here to keep `import drivers.ti` light

        self.port = port
        try:
            self.serial = serial_obj if serial_obj is not None else serial.serial_for_url(
                port, baudrate=baudrate, timeout=timeout)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open serial port {port!r} at {baudrate} baud: {exc}") from exc
        self.eof = False

    def read(self, max_bytes: int = 65536) -> bytes:
        ser = self.serial
        if ser is None:
            return b""
        try:
            waiting = ser.in_waiting
            return ser.read(max(1, min(waiting, max_bytes)))
        except OSError as exc:  # serial.SerialException is an OSError
            raise DeviceError(f"serial port {self.port!r}: {exc}") from exc

    def write(self, data: bytes) -> int:
        """Write to the port (loop:// and tests)."""
        return self.serial.write(data)

    def close(self) -> None:
        ser, self.serial = getattr(self, "serial", None), None
        if ser is not None:
            ser.close()


class FileSource(ByteSource):
    """A raw capture file, replayed as fast as possible or paced.

    pace: None (as fast as possible), "frames" (recorded frame pace: `frame_period_s`,
    `speed`), or "baud" (`baudrate` / 10 bytes per second). `sleep`/`clock` are injectable
    for tests.
    """

    def __init__(self, path: str | Path, pace: str | None = None, frame_period_s: float = 0.05,
                 speed: float = 1.0, baudrate: int = DATA_BAUD, chunk: int = 65536,
                 max_jump: int = 1000, sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if pace not in (None, "frames", "baud"):
            raise ConfigError(f"pace must be None, 'frames' or 'baud', not {pace!r}")
        if frame_period_s <= 0 or speed <= 0 or baudrate <= 0:
            raise ConfigError("frame period, speed and baud rate must be > 0")
        self.path = Path(path)
        try:
            self._f = open(self.path, "rb")  # noqa: SIM115 (closed by close())
        except OSError as exc:
            raise DeviceError(f"cannot open capture {self.path}: {exc}") from exc
        self.size = os.fstat(self._f.fileno()).st_size
        self.pace, self.period, self.speed = pace, frame_period_s, speed
        self.byte_rate = baudrate / 10.0
        self.chunk, self.max_jump = chunk, max_jump
        self._sleep, self._clock = sleep, clock
        self._pending = b""      # read from the file, not yet handed out
        self._file_eof = False
        self._t0: float | None = None
        self._fn0 = 0
        self._last_fn: int | None = None
        self._sent = 0
        self.eof = self.size == 0

    def _fill(self, want: int) -> None:
        while not self._file_eof and len(self._pending) < want:
            data = self._f.read(self.chunk)
            if not data:
                self._file_eof = True
            self._pending += data

    def read(self, max_bytes: int = 65536) -> bytes:
        if self._f is None or self.eof:
            return b""
        if self.pace == "frames":
            out = self._read_frame_paced()
        elif self.pace == "baud":
            out = self._read_baud_paced(max_bytes)
        else:
            self._fill(max_bytes)
            out, self._pending = self._pending[:max_bytes], self._pending[max_bytes:]
        self.eof = self._file_eof and not self._pending
        return out

    def _read_baud_paced(self, max_bytes: int) -> bytes:
        n = max(1, min(max_bytes, int(self.byte_rate * 0.01)))  # ~10 ms of line time
        self._fill(n)
        out, self._pending = self._pending[:n], self._pending[n:]
        if self._t0 is None:
            self._t0 = self._clock()
        self._sent += len(out)
        wait = self._t0 + self._sent / (self.byte_rate * self.speed) - self._clock()
        if wait > 0:
            self._sleep(wait)
        return out

    def _read_frame_paced(self) -> bytes:
        """Bytes from one magic word up to the next, released at its frame's due time."""
        self._fill(32)
        first = self._pending.find(MAGIC)
        if first != 0:  # leading junk (or no magic at all): hand it out at once
            while first < 0 and not self._file_eof:
                self._fill(len(self._pending) + self.chunk)
                first = self._pending.find(MAGIC)
            cut = len(self._pending) if first < 0 else first
            out, self._pending = self._pending[:cut], self._pending[cut:]
            return out
        nxt = self._pending.find(MAGIC, 1)
        while nxt < 0 and not self._file_eof:
            self._fill(len(self._pending) + self.chunk)
            nxt = self._pending.find(MAGIC, 1)
        cut = len(self._pending) if nxt < 0 else nxt
        out, self._pending = self._pending[:cut], self._pending[cut:]
        if len(out) >= 24:
            self._wait_for(struct.unpack_from("<I", out, 20)[0])
        return out

    def _wait_for(self, fn: int) -> None:
        now = self._clock()
        if self._t0 is None or self._last_fn is None or fn <= self._last_fn \
                or fn - self._last_fn > self.max_jump:
            if self._t0 is not None:
                log.debug("replay pace rebased at frame %d", fn)
            # rebase: this frame is due one period after the previous one (or now)
            base = now if self._t0 is None or self._last_fn is None else \
                max(now, self._due(self._last_fn) + self.period / self.speed)
            self._t0, self._fn0 = base, fn
        self._last_fn = fn
        wait = self._due(fn) - now
        if wait > 0:
            self._sleep(wait)

    def _due(self, fn: int) -> float:
        assert self._t0 is not None
        return self._t0 + (fn - self._fn0) * self.period / self.speed

    def close(self) -> None:
        f, self._f = getattr(self, "_f", None), None
        if f is not None:
            f.close()


def open_source(spec: str, *, baudrate: int = DATA_BAUD, timeout: float = 0.05,
                frame_period_s: float | None = None) -> ByteSource:
    """A byte source from a string (see module doc). `frame_period_s` is the default
    period of ``pace=frames`` (e.g. the cfg's frame period)."""
    if spec.startswith("file:"):
        path, _, query = spec[5:].partition("?")
        q = {k: v[-1] for k, v in parse_qs(query).items()}
        unknown = set(q) - {"pace", "period", "speed", "baud"}
        if unknown:
            raise ConfigError(f"{spec}: unknown replay option(s) {sorted(unknown)}")
        try:
            return FileSource(path, pace=q.get("pace"),
                              frame_period_s=float(q.get("period", frame_period_s or 0.05)),
                              speed=float(q.get("speed", 1.0)), baudrate=int(q.get("baud", baudrate)))
        except ValueError as exc:
            raise ConfigError(f"{spec}: {exc}") from exc
    if "://" not in spec and Path(spec).is_file():
        return FileSource(spec)
    return SerialSource(spec, baudrate=baudrate, timeout=timeout)
