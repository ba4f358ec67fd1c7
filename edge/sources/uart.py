"""TI radar on a serial data port (921600 8N1): raw bytes -> TI streaming reader -> frames.

The bytes are handed to `raw_sink` (the field log) as they arrive, then to
`mmatch.drivers.ti.reader.TlvReader`, which resynchronises on junk and counts rejects. A port
that disappears (USB unplug) raises `DeviceError`; the loop reopens it, and the reader
state starts fresh (a frame cut by the unplug is dropped and counted).
Optionally the chirp profile is sent over the CLI port at open. A frame's stamp is its
receive time (host clock, synchronised by GNSS/PTP) minus its time on the wire.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from typing import Any

from mmatch.edge.config import VehicleConfig
from mmatch.edge.sources.base import RadarSource
from mmatch.errors import DeviceError
from mmatch.types import RadarFrame

log = logging.getLogger(__name__)


class UartRadar(RadarSource):
    """`radar.port` may be a device path or a pyserial URL (loop://, socket://...)."""

    def __init__(self, cfg: VehicleConfig, **kw: Any) -> None:
        self.cfg = cfg
        self.port = cfg.radar.port
        self._ser: Any = None
        self._reader: Any = None
        self._pending: deque[RadarFrame] = deque()
        self._stats_total: dict[str, int] = {"opens": 0, "bytes": 0}
        self._frames = 0
        self.radar_cfg = None
        if cfg.radar.cfg:  # a bad profile fails at start, naming the line, before anything is sent
            from mmatch.drivers.ti.cfg import load_cfg

            self.radar_cfg = load_cfg(cfg.radar.cfg)

    def open(self) -> None:
        import serial

        from mmatch.drivers.ti.reader import TlvReader

        if self.cfg.radar.cli_port and self.cfg.radar.cfg:
            self._configure()
        try:
            self._ser = serial.serial_for_url(self.port, baudrate=self.cfg.radar.baudrate,
                                              timeout=0.05, exclusive=None)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"radar uart {self.port}: cannot open: {exc}") from exc
        chirp = self.radar_cfg.chirp if self.radar_cfg is not None else None
        self._reader = TlvReader(on_error="log", chirp=chirp)
        self._stats_total["opens"] += 1
        log.info("radar uart open: %s at %d baud", self.port, self.cfg.radar.baudrate)

    def _configure(self) -> None:
        """Send the chirp profile over the CLI port (again after every reopen: a replugged
        radar has rebooted unconfigured)."""
        from mmatch.drivers.ti.config_sender import send_cfg

        send_cfg(self.cfg.radar.cli_port, self.radar_cfg)
        log.info("radar configured over %s with %s", self.cfg.radar.cli_port, self.cfg.radar.cfg)

    def read(self, timeout: float) -> RadarFrame | None:
        if self._ser is None:
            raise DeviceError(f"radar uart {self.port}: not open")
        import serial

        deadline = time.monotonic() + timeout
        while not self._pending:
            try:
                n = max(1, min(self._ser.in_waiting, 65536))
                data = self._ser.read(n)
            except (serial.SerialException, OSError, TypeError) as exc:
                # pyserial raises TypeError/OSError from in_waiting on a vanished device
                raise DeviceError(f"radar uart {self.port}: {exc}") from exc
            if data:
                self._stats_total["bytes"] += len(data)
                if self.raw_sink is not None:
                    self.raw_sink(data)
                now = time.time()
                for pkt in self._reader.feed(data):
                    # capture stamp: receive time minus the packet's time on the wire (8N1)
                    frame = pkt.radar_frame(now)
                    frame.stamp = now - pkt.length * 10.0 / self.cfg.radar.baudrate
                    self._pending.append(frame)
            elif time.monotonic() >= deadline:
                return None
        self._frames += 1
        return self._pending.popleft()

    def counters(self) -> dict[str, int]:
        out = dict(self._stats_total)
        if self._reader is not None:
            s = self._reader.stats
            out.update(frames=s.frames, bytes_skipped=s.bytes_skipped, rejected=s.rejected_total,
                       restarts=s.restarts, frame_gaps=s.frame_gaps)
        return out

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception as exc:
                log.debug("uart close: %s", exc)
        self._pending.clear()
