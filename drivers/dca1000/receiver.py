"""UDP receiver of the DCA1000 raw data stream (data port 4098) with frame reassembly."""

from __future__ import annotations

import logging
import select
import socket
import time
from collections.abc import Iterator

from mmatch.errors import DeviceError

from .assembler import AdcFrame, FrameAssembler
from .protocol import DATA_HEADER_BYTES, DATA_PORT, unpack_data_header

log = logging.getLogger(__name__)

DEFAULT_RCVBUF = 4 * 1024 * 1024


class DataReceiver:
    """Receive data packets on (host, port) and yield reassembled frames.

    assembler: the FrameAssembler that holds the frame size and the loss policy.
    rcvbuf: requested SO_RCVBUF in bytes (the kernel caps it at net.core.rmem_max; a smaller
        grant is logged as a warning because bursts may then overflow).
    Use as a context manager; `close()` is safe twice.
    """

    def __init__(self, assembler: FrameAssembler, host: str = "192.168.33.30", port: int = DATA_PORT,
                 rcvbuf: int = DEFAULT_RCVBUF) -> None:
        self.assembler = assembler
        self._sock: socket.socket | None = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            self._sock = None
            raise DeviceError(f"cannot open the DCA1000 data socket on {host}:{port}: {exc}") from exc
        self._sock.setblocking(False)
        granted = self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2  # Linux doubles it
        self.rcvbuf = granted
        if granted < rcvbuf:
            log.warning("socket receive buffer %d B < requested %d B; raise net.core.rmem_max", granted, rcvbuf)
        self.address = self._sock.getsockname()
        self.short_datagrams = 0

    def __enter__(self) -> "DataReceiver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    @property
    def stats(self):
        return self.assembler.stats

    def frames(self, idle_timeout_s: float = 0.5, max_frames: int | None = None,
               deadline_s: float | None = None, flush: bool = True) -> Iterator[AdcFrame]:
        """Yield frames as they complete.

        Stops when no packet arrived for idle_timeout_s (the stream ended: pending frames are
        flushed), after max_frames frames, or after deadline_s seconds of wall time.
        """
        if self._sock is None:
            raise DeviceError("DCA1000 data receiver is closed")
        sock = self._sock
        recv_into = sock.recv_into
        add = self.assembler.add
        buf = bytearray(2048)
        mv = memoryview(buf)
        emitted = 0
        stop_at = None if deadline_s is None else time.monotonic() + deadline_s
        while True:
            try:
                n = recv_into(buf)
            except (BlockingIOError, InterruptedError):
                wait = idle_timeout_s
                if stop_at is not None:
                    wait = min(wait, max(0.0, stop_at - time.monotonic()))
                ready, _, _ = select.select([sock], [], [], wait)
                if ready:
                    continue
                break  # idle for idle_timeout_s (stream ended) or deadline reached
            if n < DATA_HEADER_BYTES:
                self.short_datagrams += 1
                self.assembler.stats.bad_packets += 1
                continue
            seq, lo, hi = unpack_data_header(buf)
            out = add(seq, lo | (hi << 32), mv[DATA_HEADER_BYTES:n])
            if out:
                for frame in out:
                    yield frame
                    emitted += 1
                    if max_frames is not None and emitted >= max_frames:
                        return
            if stop_at is not None and time.monotonic() >= stop_at:
                break
        if flush:
            for frame in self.assembler.flush():
                yield frame
                emitted += 1
                if max_frames is not None and emitted >= max_frames:
                    return
