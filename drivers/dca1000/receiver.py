"""UDP receiver of the DCA1000 raw data stream (data port 4098) with frame reassembly."""

from __future__ import annotations

import logging
import select
import socket
import time
from collections.abc import Iterator

import numpy as np

from mmatch.errors import DeviceError

from . import mmsg
from .assembler import AdcFrame, FrameAssembler
from .protocol import DATA_HEADER_BYTES, DATA_PORT, MAX_PAYLOAD_BYTES, unpack_data_header

log = logging.getLogger(__name__)

DEFAULT_RCVBUF = 4 * 1024 * 1024


class DataReceiver:
    """Receive data packets on (host, port) and yield reassembled frames.

    assembler: the FrameAssembler that holds the frame size and the loss policy.
    rcvbuf: requested SO_RCVBUF in bytes (the kernel caps it at net.core.rmem_max; a smaller
        grant is logged as a warning because bursts may then overflow).
    batch: datagrams per recvmmsg call (Linux); 1 = one recv per datagram.
    Use as a context manager; `close()` is safe twice.
    """

    def __init__(
        self,
        assembler: FrameAssembler,
        host: str = "192.168.33.30",
        port: int = DATA_PORT,
        rcvbuf: int = DEFAULT_RCVBUF,
        batch: int = 64,
    ) -> None:
        self.assembler = assembler
        self.batch = batch
        self._sock: socket.socket | None = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            self._sock = None
            raise DeviceError(
                f"cannot open the DCA1000 data socket on {host}:{port}: {exc}"
            ) from exc
        self._sock.setblocking(False)
        granted = (
            self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2
        )  # Linux doubles it
        self.rcvbuf = granted
        if granted < rcvbuf:
            log.warning(
                "socket receive buffer %d B < requested %d B; raise net.core.rmem_max",
                granted,
                rcvbuf,
            )
        self.address = self._sock.getsockname()
        self.short_datagrams = 0
        self._last_log = time.monotonic()
        self._last_bytes = 0

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

    def _summary(self, every_s: float = 5.0) -> None:
        """INFO line with rate and losses every `every_s` seconds."""
        now = time.monotonic()
        if now - self._last_log < every_s:
            return
        st = self.assembler.stats
        dt = now - self._last_log
        rate = (st.payload_bytes - self._last_bytes) / dt / 1e6
        log.info(
            "DCA1000 data: %.1f MB/s, frames %d complete / %d flagged / %d dropped / %d lost, "
            "gaps %d, out of order %d, bad %d",
            rate,
            st.frames_complete,
            st.frames_flagged,
            st.frames_dropped,
            st.frames_lost,
            st.gaps,
            st.out_of_order,
            st.bad_packets,
        )
        self._last_log = now
        self._last_bytes = st.payload_bytes

    def frames(
        self,
        idle_timeout_s: float = 0.5,
        max_frames: int | None = None,
        deadline_s: float | None = None,
        flush: bool = True,
    ) -> Iterator[AdcFrame]:
        """Yield frames as they complete.

        Stops when no packet arrived for idle_timeout_s (the stream ended: pending frames are
        flushed), after max_frames frames, or after deadline_s seconds of wall time.
        """
        if self._sock is None:
            raise DeviceError("DCA1000 data receiver is closed")
        if self.batch > 1 and mmsg.available():
            yield from self._frames_batched(idle_timeout_s, max_frames, deadline_s, flush)
            return
        sock = self._sock
        recv_into = sock.recv_into
        add = self.assembler.add
        buf = bytearray(2048)
        mv = memoryview(buf)
        emitted = 0
        stop_at = None if deadline_s is None else time.monotonic() + deadline_s
        count = 0
        while True:
            count += 1
            if count & 4095 == 0:
                self._summary()
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

    def _frames_batched(
        self, idle_timeout_s: float, max_frames: int | None, deadline_s: float | None, flush: bool
    ) -> Iterator[AdcFrame]:
        sock = self._sock
        br = mmsg.BatchReceiver(sock, self.batch, MAX_PAYLOAD_BYTES)
        asm = self.assembler
        emitted = 0
        stop_at = None if deadline_s is None else time.monotonic() + deadline_s
        while True:
            if stop_at is not None and time.monotonic() >= stop_at:
                break
            self._summary()
            n = br.recv()
            if n == 0:
                wait = idle_timeout_s
                if stop_at is not None:
                    wait = min(wait, max(0.0, stop_at - time.monotonic()))
                ready, _, _ = select.select([sock], [], [], wait)
                if ready:
                    continue
                break  # idle for idle_timeout_s (stream ended) or deadline reached
            if n < 8:  # a trickle: per-packet is cheaper than the vectorised checks
                out = []
                hmv = memoryview(br.headers).cast("B")
                pmv = memoryview(br.payload)
                lens = br.b.msg_len
                flags = br.b.msg_flags
                for i in range(n):
                    ln = int(lens[i])
                    if ln < DATA_HEADER_BYTES or flags[i] & mmsg.MSG_TRUNC:
                        self.short_datagrams += ln < DATA_HEADER_BYTES
                        asm.stats.bad_packets += 1
                        asm.stats.packets += 1
                        continue
                    sq, lo, hi = unpack_data_header(hmv, i * DATA_HEADER_BYTES)
                    o = i * MAX_PAYLOAD_BYTES
                    out += asm.add(sq, lo | (hi << 32), pmv[o : o + ln - DATA_HEADER_BYTES])
                for frame in out:
                    yield frame
                    emitted += 1
                    if max_frames is not None and emitted >= max_frames:
                        return
                continue
            seq, bc, dlen, trunc = br.fields(n)
            bad = (dlen < DATA_HEADER_BYTES) | trunc
            if bad.any():
                self.short_datagrams += int((dlen < DATA_HEADER_BYTES).sum())
                asm.stats.bad_packets += int(bad.sum())
                asm.stats.packets += int(bad.sum())
                good = np.flatnonzero(~bad)
                out = []
                mv = memoryview(br.payload)
                for i in good.tolist():
                    out += asm.add(
                        int(seq[i]),
                        int(bc[i]),
                        mv[
                            i * MAX_PAYLOAD_BYTES : i * MAX_PAYLOAD_BYTES
                            + int(dlen[i])
                            - DATA_HEADER_BYTES
                        ],
                    )
            else:
                out = asm.add_batch(
                    seq, bc, dlen - DATA_HEADER_BYTES, br.payload, MAX_PAYLOAD_BYTES
                )
            for frame in out:
                yield frame
                emitted += 1
                if max_frames is not None and emitted >= max_frames:
                    return
        if flush:
            for frame in asm.flush():
                yield frame
                emitted += 1
                if max_frames is not None and emitted >= max_frames:
                    return
