"""Streaming TI UART reader: any byte source in, accepted frames and counters out.

The reader keeps a byte buffer, finds magic words with ``bytes.find``, hands each candidate
to the pure `decode_frame` and applies ti_formats.md section 0: a rejected candidate costs
its bytes and the search resumes at the next magic word after ``offset + 1``; a candidate
that is not complete yet waits for more bytes (unless a later magic word proves it
truncated, or the stream ends). Garbage never raises out of the reader unless the bad-input
policy is ``"raise"`` (a debugging aid); the default ``"log"`` logs each rejection and
``"skip"`` only counts it.

Counters (`ReaderStats`): frames accepted, bytes in, bytes skipped (junk and rejected
frames), rejections by reason with their stream offsets, TLV types seen, unknown TLVs,
sensor restarts (frame number going back) and frame-number gaps.
"""

from __future__ import annotations

import logging
import struct
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from mmatch.drivers.ti.decoder import (
    MAX_PACKET_LEN, NEED_MORE, OK, REJECT, DecodeResult, TiPacket, decode_frame)
from mmatch.drivers.ti.header import MAGIC, HeaderFormat
from mmatch.drivers.ti.tlv import RawTlv
from mmatch.errors import ConfigError, DecodeError
from mmatch.types import RadarFrame

if TYPE_CHECKING:
    from mmatch.drivers.ti.cfg import ChirpParams
    from mmatch.drivers.ti.sources import ByteSource

log = logging.getLogger(__name__)

POLICIES = ("skip", "log", "raise")
_U32 = struct.Struct("<I")
DATA_BAUD = 921600
NO_FRAME_HINT_BYTES = 65536
"""After this many bytes without a single frame the reader logs a wrong-port/baud hint once
(a data port left at 115200, or the CLI port, shows up as bytes without magic words)."""


@dataclass
class ReaderStats:
    """Counters of one reader (stream offsets are absolute byte positions)."""

    frames: int = 0
    bytes_in: int = 0
    bytes_skipped: int = 0
    rejected: Counter = field(default_factory=Counter)
    rejections: list = field(default_factory=list)  # (offset, reason), the first `keep` ones
    tlv_types: Counter = field(default_factory=Counter)
    unknown_tlvs: int = 0
    malformed_tlvs: int = 0  # known side TLVs of an unexpected size, kept raw
    restarts: int = 0  # (frame number, sub-frame) went back or repeated: sensor restart
    frame_gaps: int = 0  # frames missing between consecutive accepted frame numbers
    formats: Counter = field(default_factory=Counter)

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    def as_dict(self) -> dict:
        return {"frames": self.frames, "bytes_in": self.bytes_in,
                "bytes_skipped": self.bytes_skipped, "rejected": dict(self.rejected),
                "tlv_types": {str(k): v for k, v in sorted(self.tlv_types.items())},
                "unknown_tlvs": self.unknown_tlvs, "malformed_tlvs": self.malformed_tlvs,
                "restarts": self.restarts,
                "frame_gaps": self.frame_gaps, "formats": dict(self.formats)}


class TlvReader:
    """Incremental TLV frame reader.

    Push bytes with `feed` (returns the packets they complete) and `finish` at the end of
    the stream, or give a `ByteSource` and iterate `packets()` / `frames()`, or poll
    `read_frame(timeout)` on a live port.

    on_error: "skip" | "log" | "raise" (bad-input policy). chirp: cfg parameters (only used
    to scale SDK 1.x/2.x Doppler indices). keep: how many (offset, reason) rejections to keep.
    clock: host clock for receive times (s).
    """

    def __init__(self, source: ByteSource | None = None, *, on_error: str = "log",
                 chirp: ChirpParams | None = None, keep: int = 10000,
                 clock: Callable[[], float] = time.time, read_size: int = 65536) -> None:
        if on_error not in POLICIES:
            raise ConfigError(f"on_error must be one of {POLICIES}, not {on_error!r}")
        self.source = source
        self.on_error = on_error
        self.chirp = chirp
        self.keep = keep
        self.clock = clock
        self.read_size = read_size
        self.stats = ReaderStats()
        self._buf = bytearray()  # appended in place: no quadratic copying while a big frame arrives
        self._base = 0      # stream offset of _buf[0]
        self._pos = 0       # first byte of _buf not yet accounted for (accepted or skipped)
        self._search = 0    # where the next magic search starts
        self._fmt: HeaderFormat | None = None
        self._last_key: tuple[int, int] | None = None
        self._pending: deque[TiPacket] = deque()
        self._carry: list[TiPacket] = []  # accepted before a "raise" policy error
        self._finished = False
        self._hinted = False
        self._wait: tuple[int, int, int] | None = None  # (frame start, bytes needed, scanned) in _buf

    # ---- push interface ----------------------------------------------------------------
    def feed(self, data: bytes) -> list[TiPacket]:
        """Add bytes; return the packets they complete (in stream order)."""
        if data:
            self.stats.bytes_in += len(data)
            self._buf += data
        return self._scan(final=False)

    def finish(self) -> list[TiPacket]:
        """End of stream: decide on what is left (a partial frame is "truncated")."""
        if self._finished:
            return []
        self._finished = True
        return self._scan(final=True)

    # ---- pull interface ----------------------------------------------------------------
    def packets(self) -> Iterator[TiPacket]:
        """Packets from the source until it reaches its end (forever on a live port)."""
        if self.source is None:
            raise ValueError("TlvReader.packets() needs a source")
        while True:
            while self._pending:
                yield self._pending.popleft()
            data = self.source.read(self.read_size)
            if data:
                self._pending.extend(self.feed(data))
            elif self.source.eof:
                self._pending.extend(self.finish())
                while self._pending:
                    yield self._pending.popleft()
                return

    def frames(self) -> Iterator[RadarFrame]:
        """Like `packets()`, as `mmatch.types.RadarFrame` (host_time = receive time)."""
        for p in self.packets():
            yield self.to_radar_frame(p)

    def read_frame(self, timeout: float | None = None) -> RadarFrame | None:
        """The next frame from the source, or None after `timeout` s or at its end."""
        if self.source is None:
            raise ValueError("TlvReader.read_frame() needs a source")
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._pending:
            if deadline is not None and time.monotonic() >= deadline:
                return None
            data = self.source.read(self.read_size)
            if data:
                self._pending.extend(self.feed(data))
            elif self.source.eof:
                self._pending.extend(self.finish())
                if not self._pending:
                    return None
        return self.to_radar_frame(self._pending.popleft())

    @staticmethod
    def to_radar_frame(packet: TiPacket) -> RadarFrame:
        return packet.radar_frame()

    # ---- core --------------------------------------------------------------------------
    def _scan(self, final: bool) -> list[TiPacket]:
        buf, pos, search = self._buf, self._pos, self._search
        st = self.stats
        out, self._carry = self._carry, []
        now: float | None = None
        find = buf.find
        if self._wait is not None and not final:
            # a big frame still arriving: only look at the new bytes for a magic word that
            # would cut it short, instead of decoding it again from the start
            i, need, scanned = self._wait
            if len(buf) < need and find(MAGIC, max(i + 8, scanned - len(MAGIC) + 1)) < 0:
                self._wait = (i, need, len(buf))
                return out
        self._wait = None
        while True:
            i = find(MAGIC, search)
            if i < 0:
                keep_from = len(buf) if final else max(pos, len(buf) - (len(MAGIC) - 1))
                if keep_from > pos:
                    st.bytes_skipped += keep_from - pos
                    pos = keep_from
                search = pos
                break
            if i > pos:
                st.bytes_skipped += i - pos
                pos = i
            try:
                res = decode_frame(buf, i, final=final, prefer=self._fmt, chirp=self.chirp)
            except Exception as exc:  # a decoder bug must not stop a live radar
                log.exception("decoder failed on the frame at byte %d", self._base + i)
                res = DecodeResult(REJECT, reason="internal_error", detail=repr(exc))
            if res.status == OK:
                pkt = res.packet
                assert pkt is not None
                if now is None:
                    now = self.clock()
                pkt = replace(pkt, host_time=now, offset=self._base + i)
                self._accept(pkt)
                out.append(pkt)
                pos = search = i + res.length
            elif res.status == NEED_MORE:
                search = i
                if len(buf) - i >= 16:
                    total = _U32.unpack_from(buf, i + 12)[0]
                    if len(buf) < i + total <= i + MAX_PACKET_LEN:
                        self._wait = (i - pos, i + total - pos, len(buf) - pos)  # after _save
                break
            else:
                search = i + 1
                offset = self._base + i
                if self.on_error == "raise":
                    self._save(buf, pos, search)
                    self._carry = out
                self._reject(offset, res.reason, res.detail)
        self._save(buf, pos, search)
        if not self._hinted and st.frames == 0 and st.bytes_skipped >= NO_FRAME_HINT_BYTES:
            self._hinted = True
            log.warning("%d bytes and no frame: is this the data port (not the CLI port), at %d "
                        "baud, with a demo firmware that outputs TLVs?", st.bytes_skipped, DATA_BAUD)
        return out

    def _save(self, buf: bytearray, pos: int, search: int) -> None:
        if pos:
            self._base += pos
            del buf[:pos]
            search -= pos
            pos = 0
        self._buf, self._pos, self._search = buf, pos, search

    def _accept(self, pkt: TiPacket) -> None:
        st = self.stats
        st.frames += 1
        hdr = pkt.header
        self._fmt = hdr.fmt
        st.formats[hdr.fmt.value] += 1
        for t in pkt.tlvs:
            st.tlv_types[int(t.type)] += 1
            if isinstance(t, RawTlv):
                st.unknown_tlvs += 1
        if pkt.malformed_tlvs:
            st.malformed_tlvs += len(pkt.malformed_tlvs)
            st.unknown_tlvs -= len(pkt.malformed_tlvs)
        # advanced-frame sub-frames share a frame number: order by (frame, sub-frame)
        key = (hdr.frame_number, hdr.sub_frame_number)
        last = self._last_key
        if last is not None:
            if key <= last:
                st.restarts += 1
                log.info("frame number went back from %d to %d: sensor restart", last[0], key[0])
            elif key[0] > last[0] + 1:
                st.frame_gaps += key[0] - last[0] - 1
        self._last_key = key

    def _reject(self, offset: int, reason: str, detail: str) -> None:
        st = self.stats
        st.rejected[reason] += 1
        if len(st.rejections) < self.keep:
            st.rejections.append((offset, reason))
        if self.on_error == "log":
            log.warning("frame at byte %d rejected: %s (%s)", offset, reason, detail)
        elif self.on_error == "raise":
            raise DecodeError(f"frame at byte {offset} rejected: {reason} ({detail})")


def read_all(data: bytes, *, on_error: str = "skip", chirp: ChirpParams | None = None,
             chunk: int | None = None) -> tuple[list[TiPacket], ReaderStats]:
    """Decode a whole byte string (optionally fed in `chunk`-byte pieces)."""
    r = TlvReader(on_error=on_error, chirp=chirp)
    out: list[TiPacket] = []
    if chunk:
        for k in range(0, len(data), chunk):
            out += r.feed(data[k:k + chunk])
    else:
        out += r.feed(data)
    out += r.finish()
    return out, r.stats
