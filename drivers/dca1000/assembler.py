"""Frame reassembly of the DCA1000 raw data stream (pure: no sockets).

Each data packet says how many payload bytes were sent before it (`byte_count`), so its bytes
belong at stream offset `byte_count`; frame k occupies stream bytes [k*F, (k+1)*F) where F is the
raw frame size. Packets are not aligned to frames: one packet can end a frame and start the next.

Policy:
* Packets may arrive out of order; a frame waits until it is complete, or until the stream has
  moved `reorder_bytes` past its end (or the stream ends): it is then emitted zero-filled and
  flagged (`policy="flag"`, default) or counted and withheld (`policy="drop"`).
* A frame that received no byte at all is never emitted; it is counted in `frames_lost`
  (the `index` of the next emitted frame shows the gap).
* A packet whose byte count contradicts its sequence number (`byte_count != (seq-1)*P` once the
  packet size P is known), whose payload is empty or longer than 1456 B, or that jumps more than
  `max_jump_frames` ahead is counted in `bad_packets` and dropped, so it cannot shift later frames;
  the frame it should have filled stays incomplete and is flagged.
* Duplicates are counted and ignored; packets for frames already emitted are counted as `late`.
* Frames are always emitted in increasing index order. Frame indices count from the stream's
  byte 0 (RECORD_START), so a receiver that joins late still cuts frames where the radar did;
  the frame it joined inside is flagged.
* The padding after the last frame (the FPGA zero-fills its last packet) is ignored when the
  number of frames is known; otherwise a frame still open at the end is counted as truncated.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .protocol import MAX_PAYLOAD_BYTES

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class AdcFrame:
    """One raw ADC frame.

    index: frame number since the start of the recording (stream offset // frame size).
    data: uint8 (frame_bytes,) raw bytes in the radar's LVDS layout; gaps are zeros.
    complete: False when bytes were missing (zero-filled).
    missing_bytes: number of zero-filled bytes.
    """

    index: int
    data: np.ndarray
    complete: bool
    missing_bytes: int = 0


@dataclass
class StreamStats:
    """Counters of one data stream."""

    packets: int = 0
    payload_bytes: int = 0
    gaps: int = 0  # places where the byte count jumped forward (lost packets)
    lost_bytes_est: int = 0  # bytes skipped at those jumps (reordered ones come back later)
    out_of_order: int = 0
    duplicates: int = 0
    late: int = 0
    bad_packets: int = 0
    beyond_end: int = 0  # packets or parts after the last expected frame (padding)
    frames_complete: int = 0
    frames_flagged: int = 0
    frames_dropped: int = 0
    frames_lost: int = 0
    frames_truncated: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class _Pending:
    buf: bytearray
    got: int = 0
    starts: set = field(default_factory=set)


class FrameAssembler:
    """Reassemble frames of `frame_bytes` from (seq, byte_count, payload) packets.

    num_frames: frames in the recording when known (cfg frameCfg); bytes after them are padding,
        and at the end every incomplete frame is flagged. When unknown, a frame still open when the
        stream ends is counted as `frames_truncated` and not emitted.
    reorder_bytes: how far the stream may run ahead of an incomplete frame before it is given up.
    packet_bytes: payload size of every packet when known; otherwise learnt from the first packet.
    """

    def __init__(
        self,
        frame_bytes: int,
        num_frames: int | None = None,
        policy: str = "flag",
        reorder_bytes: int = 64 * MAX_PAYLOAD_BYTES,
        packet_bytes: int | None = None,
        check_seq: bool = True,
        max_jump_frames: int = 1024,
    ) -> None:
        if frame_bytes <= 0:
            raise ValueError(f"frame_bytes must be > 0, got {frame_bytes}")
        if policy not in ("flag", "drop"):
            raise ValueError(f"policy must be 'flag' or 'drop', got {policy!r}")
        self.frame_bytes = frame_bytes
        self.num_frames = num_frames if num_frames and num_frames > 0 else None
        self.end_byte = self.num_frames * frame_bytes if self.num_frames else None
        self.policy = policy
        self.reorder_bytes = reorder_bytes
        self.packet_bytes = packet_bytes
        self.check_seq = check_seq
        self.max_jump_bytes = max_jump_frames * frame_bytes
        self.stats = StreamStats()
        self._pending: dict[int, _Pending] = {}
        self._next: int | None = None  # index of the next frame to emit
        self._high = 0  # highest stream byte seen (exclusive)
        self._expect: int | None = None  # byte count expected for the next in-order packet
        self._emitted = False

    # ------------------------------------------------------------------------------------------
    def add(self, seq: int, byte_count: int, payload) -> list[AdcFrame]:
        """Feed one packet (payload: bytes-like); returns the frames it lets go, in order."""
        st = self.stats
        n = len(payload)
        st.packets += 1
        if n == 0 or n > MAX_PAYLOAD_BYTES:
            st.bad_packets += 1
            log.debug("packet seq %d: impossible payload length %d", seq, n)
            return []
        if self.packet_bytes is None:
            self.packet_bytes = n
        if self.check_seq and byte_count != (seq - 1) * self.packet_bytes:
            st.bad_packets += 1
            log.debug(
                "packet seq %d: byte count %d contradicts the sequence number", seq, byte_count
            )
            return []
        if self._expect is not None and byte_count - self._high > self.max_jump_bytes:
            st.bad_packets += 1
            log.debug("packet seq %d: byte count %d jumps too far ahead", seq, byte_count)
            return []
        st.payload_bytes += n
        end = byte_count + n
        if self._expect is None:
            self._expect = end
        elif byte_count == self._expect:
            self._expect = end
        elif byte_count > self._expect:
            st.gaps += 1
            st.lost_bytes_est += byte_count - self._expect
            self._expect = end
        else:
            st.out_of_order += 1
        if self.end_byte is not None and end > self.end_byte:
            st.beyond_end += 1
            end = self.end_byte
            n = end - byte_count
            if n <= 0:
                return self._release(False)
        F = self.frame_bytes
        k = byte_count // F
        if self._next is None:
            # the first packet may itself be a reordered one: earlier frames within the reorder
            # window stay open (frames that then get no byte at all are counted as lost)
            self._next = max(0, byte_count - self.reorder_bytes) // F
        elif k < self._next and not self._emitted:
            self._next = k
        elif k < self._next:
            if (end - 1) // F < self._next:
                st.late += 1
                return []
        if end > self._high:
            self._high = end
        pos = byte_count
        src = 0
        mv = memoryview(payload)
        while pos < end:
            k = pos // F
            off = pos - k * F
            take = min(end - pos, F - off)
            if k >= self._next:
                p = self._pending.get(k)
                if p is None:
                    p = self._pending[k] = _Pending(bytearray(F))
                if byte_count in p.starts:
                    st.duplicates += 1
                    return self._release(False)
                p.starts.add(byte_count)
                p.buf[off : off + take] = mv[src : src + take]
                p.got += take
            pos += take
            src += take
        return self._release(False)

    def add_batch(
        self,
        seq: np.ndarray,
        byte_count: np.ndarray,
        length: np.ndarray,
        payload: np.ndarray,
        slot_bytes: int,
    ) -> list[AdcFrame]:
        """Feed n packets at once: payload of packet i is payload[i*slot_bytes:][:length[i]].

        A run of full-size, in-order packets that continues the stream is written as one
        segment (vectorised checks); anything else goes packet by packet through `add`.
        """
        n = len(seq)
        if n == 0:
            return []
        P = self.packet_bytes
        bc0 = int(byte_count[0])
        fast = (
            P == slot_bytes
            and self._expect is not None
            and bc0 == self._expect
            and bc0 >= self._high
            and (self.end_byte is None or bc0 + n * P <= self.end_byte)
            and bool(np.all(length == P))
            and bool(np.all(np.diff(byte_count) == P))
            and (not self.check_seq or bool(np.all(byte_count == (seq - 1) * P)))
            and bc0 + n * P - self._high <= self.max_jump_bytes
        )
        if not fast:
            out: list[AdcFrame] = []
            mv = memoryview(payload)
            for i, (s, b, ln) in enumerate(
                zip(seq.tolist(), byte_count.tolist(), length.tolist(), strict=True)
            ):
                out += self.add(s, b, mv[i * slot_bytes : i * slot_bytes + ln])
            return out
        st = self.stats
        st.packets += n
        st.payload_bytes += n * P
        end = bc0 + n * P
        self._expect = end
        self._high = end
        F = self.frame_bytes
        mv = memoryview(payload)
        pos = bc0
        src = 0
        while pos < end:
            k = pos // F
            off = pos - k * F
            take = min(end - pos, F - off)
            if k >= self._next:
                p = self._pending.get(k)
                if p is None:
                    p = self._pending[k] = _Pending(bytearray(F))
                p.buf[off : off + take] = mv[src : src + take]
                p.got += take
                first = pos - (pos - bc0) % P  # start of the packet holding byte `pos`
                p.starts.update(range(first, pos + take, P))
            pos += take
            src += take
        return self._release(False)

    def flush(self) -> list[AdcFrame]:
        """The stream has ended: let every pending frame go (see the class policy)."""
        return self._release(True)

    # ------------------------------------------------------------------------------------------
    def _release(self, final: bool) -> list[AdcFrame]:
        out: list[AdcFrame] = []
        try:
            self._release_into(out, final)
        finally:
            self._emitted = (
                self._emitted
                or bool(out)
                or self.stats.frames_dropped > 0
                or self.stats.frames_lost > 0
            )
        return out

    def _release_into(self, out: list, final: bool) -> None:
        F = self.frame_bytes
        st = self.stats
        while self._pending and self._next is not None:
            k = self._next
            p = self._pending.get(k)
            if p is None:
                nxt = min(self._pending)
                if not final:  # frames the stream has passed by reorder_bytes may be given up
                    nxt = min(nxt, max(k, (self._high - self.reorder_bytes) // F))
                    if nxt == k:
                        break
                st.frames_lost += nxt - k
                self._next = nxt
                continue
            if p.got >= F:
                del self._pending[k]
                st.frames_complete += 1
                out.append(AdcFrame(k, np.frombuffer(p.buf, dtype=np.uint8), True, 0))
                self._next = k + 1
                continue
            if not final and self._high < (k + 1) * F + self.reorder_bytes:
                break
            del self._pending[k]
            self._next = k + 1
            if final and self.num_frames is None and not self._pending:
                st.frames_truncated += 1
                log.debug(
                    "frame %d open at the end of the stream (%d of %d bytes): truncated",
                    k,
                    p.got,
                    F,
                )
                continue
            missing = F - p.got
            if self.policy == "flag":
                st.frames_flagged += 1
                out.append(AdcFrame(k, np.frombuffer(p.buf, dtype=np.uint8), False, missing))
            else:
                st.frames_dropped += 1
            log.debug("frame %d incomplete: %d bytes missing", k, missing)
