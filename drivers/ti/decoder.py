"""Pure TI UART frame decoder: bytes at an offset -> one frame, a rejection, or "need more".

`decode_frame` applies the acceptance rule of ti_formats.md section 0, in this order:
magic word at `offset`; no other magic word starting inside the header; header complete;
sane totalPacketLen; the packet fits in the data (otherwise: wait for more bytes, unless the
stream is final or a later magic word inside the declared packet proves it cut short); no
other magic word starting inside [offset+8, offset+len) (one may run past the end); for the
48-byte format the header checksum; all numTLVs TLV headers and payloads inside the packet;
each point TLV well-formed (other known TLVs of an unexpected size are kept raw and listed
in `TiPacket.malformed_tlvs`, costing only themselves); padding after the last TLV < 32
bytes with the packet a multiple of 32 bytes (36/40-byte formats, SDK >= 2) or none
(48-byte format); for SDK >= 3 TLV 1 holds numDetectedObj points (or length 0 when
numDetectedObj is 0, the SDK 3.3 quirk); TLV 7, when present, one entry per point; finite
point values. Verdicts and their reasons do not depend on how the bytes were chunked.

It never raises on bad bytes: every failure is a `DecodeResult` with a reason from
`REASONS`.

Points come out as mmatch points, float32 (N, 5) x, y, z (m), doppler (m/s, radial,
positive = range increasing), snr (dB), from the first point TLV of the frame:

* TLV 1 float (SDK 3.x): x, y, z, velocity; snr = TLV 7 snr x 0.1 dB, **0.0 when the frame
  has no TLV 7** (guiMonitor detectedObjects 2, or the SDK 3.3 empty-frame quirk).
* TLV 1 Q-format (SDK 1.x/2.x): x, y, z = raw / 2**q; doppler = signed dopplerIdx x the
  Doppler resolution of the cfg passed as `chirp` (indices >= numDopplerBins/2 wrapped),
  **0.0 without a cfg**; snr = TLV 7 when present, else **0.0: this format carries no SNR**
  (peakVal is a log-magnitude, kept in the `DetectedPointsQ` message).
* TLV 301 (L-SDK): raw x unit for x, y, z, doppler; snr x snrUnit (dB).
* TLV 1020 / 48-B TLV 6 (compressed spherical): r, azimuth, elevation, doppler x units;
  x = r cos(el) sin(az), y = r cos(el) cos(az), z = r sin(el); snr is a linear ratio on the
  wire, converted to 10 log10(ratio) dB, floored at -30 dB (ratio 0).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mmatch.drivers.ti.header import MAGIC, FrameHeader, HeaderFormat, candidate_formats, version_major
from mmatch.drivers.ti.tlv import (
    OOB_TLVS, PC3D_TLVS, POINT_F32, CompressedPoints, DetectedPoints, DetectedPointsQ,
    ExtDetectedPoints, RawTlv, SideInfo, TlvMessage)
from mmatch.errors import DecodeError
from mmatch.types import RadarFrame

if TYPE_CHECKING:
    from mmatch.drivers.ti.cfg import ChirpParams

MAX_PACKET_LEN = 4 * 1024 * 1024
"""Largest totalPacketLen accepted (bytes); a longer one is a corrupted length."""

SEGMENT = 32
"""SDK 2.x/3.x pad packets to a multiple of this (MMWDEMO_OUTPUT_MSG_SEGMENT_LEN)."""

SNR_FLOOR_DB = -30.0

OK, NEED_MORE, REJECT = "ok", "need_more", "reject"

REASONS: tuple[str, ...] = (
    "truncated",            # the stream ends inside the frame
    "bad_length",           # totalPacketLen smaller than the header or absurdly large
    "magic_inside_packet",  # another magic word starts inside the header or declared packet
                            # (a frame cut short by lost bytes: the next frame begins in it)
    "header_checksum",      # 48-byte people-counting header checksum fails
    "tlv_out_of_bounds",    # a TLV header or payload runs past the packet
    "bad_tlv_length",       # a TLV length that cannot be (48-B format length < 8)
    "bad_tlv_payload",      # a point TLV (1, 7, 301, 1020; 6 in the 48-B format) that does not parse,
                            # or non-finite point values
    "padding",              # >= 32 bytes after the last TLV, or not a 32-byte multiple
    "point_count",          # TLV 1 / TLV 7 disagree with numDetectedObj
    "no_magic",             # decode_frame called where no magic word starts
    "internal_error",       # the decoder itself failed (a bug; logged with its traceback)
)

_TLV_HDR = struct.Struct("<2I")
_U32 = struct.Struct("<I")
# TLVs that carry the points: a malformed one rejects the frame (others are kept raw)
_POINT_TLVS = frozenset({1, 7, 301, 1020})
_PC3D_POINT_TLVS = frozenset({6})
_HEAD_REGION = 48 + len(MAGIC) - 1  # largest header + where a magic word starting in it ends
_EMPTY5 = np.zeros((0, 5), np.float32)


@dataclass(frozen=True)
class TiPacket:
    """One accepted UART frame: header, TLV messages in wire order, mmatch points."""

    header: FrameHeader
    tlvs: tuple[TlvMessage, ...]
    points: np.ndarray
    offset: int
    length: int
    host_time: float = 0.0
    malformed_tlvs: tuple[int, ...] = ()  # types of known TLVs whose payload did not parse (kept raw)

    def tlv(self, tlv_type: int) -> TlvMessage | None:
        """The first TLV of a type, or None."""
        for t in self.tlvs:
            if t.type == tlv_type:
                return t
        return None

    def radar_frame(self, host_time: float | None = None) -> RadarFrame:
        """As an `mmatch.types.RadarFrame`; stamp = host receive time (s), `self.host_time`
        unless given (the reader sets it when the packet completes)."""
        t = self.host_time if host_time is None else host_time
        return RadarFrame(points=self.points, stamp=t, frame_number=self.header.frame_number,
                          host_time=t, device=self.header.device_fields())


@dataclass(frozen=True)
class DecodeResult:
    """status: "ok" (packet set, `length` bytes consumed), "need_more" (wait for bytes) or
    "reject" (`reason` from REASONS, `detail` for humans)."""

    status: str
    packet: TiPacket | None = None
    length: int = 0
    reason: str = ""
    detail: str = ""


def _reject(reason: str, detail: str) -> DecodeResult:
    return DecodeResult(REJECT, reason=reason, detail=detail)


_NEED_MORE = DecodeResult(NEED_MORE)


def decode_frame(buf: bytes | bytearray, offset: int = 0, end: int | None = None, *,
                 final: bool = True, prefer: HeaderFormat | None = None,
                 chirp: ChirpParams | None = None) -> DecodeResult:
    """Decode the frame whose magic word starts at `buf[offset]` (pure; never raises on data).

    end: end of valid data (default len(buf)). final: no more bytes will come (a short frame
    is then "truncated" instead of "need_more"). prefer: the header format the stream has
    been using, tried first and used to name the reason of a rejection. chirp: cfg-derived
    parameters, used only to scale SDK 1.x/2.x Doppler indices to m/s.
    """
    if end is None:
        end = len(buf)
    avail = end - offset
    if buf[offset:offset + 8] != MAGIC:
        return _reject("no_magic", "no magic word at offset")  # caller error; never from the reader
    # Decide nothing before the largest header plus a magic word's length is in (or the
    # stream ended, or a later magic word shows up): the verdict, and its reason, then do
    # not depend on how the bytes were chunked.
    if avail < _HEAD_REGION and not final and _later_magic(buf, offset, end) < 0:
        return _NEED_MORE
    head_stop = offset + _HEAD_REGION
    if avail >= 16:  # a tiny unpadded packet (SDK 1.x, no TLVs) may end inside that region
        total = _U32.unpack_from(buf, offset + 12)[0]
        if total >= HeaderFormat.H36.size:
            head_stop = min(head_stop, offset + total + len(MAGIC) - 1)
    inner = _later_magic(buf, offset, min(end, head_stop))
    if inner >= 0:
        return _reject("magic_inside_packet", f"magic word at +{inner - offset} inside the header")
    if avail < 20:
        return _reject("truncated", "stream ends inside the header")
    formats = candidate_formats(buf, offset, avail)
    if prefer is not None and prefer in formats and formats[0] is not prefer:
        formats = [prefer] + [f for f in formats if f is not prefer]
    first: DecodeResult | None = None
    for fmt in formats:
        res = _decode_as(buf, offset, end, final, fmt, chirp)
        if res.status != REJECT:
            return res
        first = first or res
    if prefer is HeaderFormat.H48 and HeaderFormat.H48 not in formats and avail >= 48:
        return _reject("header_checksum", "48-byte header checksum does not hold")
    assert first is not None
    return first


def _later_magic(buf: bytes | bytearray, offset: int, stop: int) -> int:
    return buf.find(MAGIC, offset + 8, stop)


def _magic_prefix_at_tail(buf: bytes | bytearray, lo: int, end: int) -> bool:
    """True if some buf[s:end], lo <= s < end, is a proper prefix of the magic word."""
    for s in range(max(lo, end - len(MAGIC) + 1), end):
        if MAGIC.startswith(buf[s:end]):
            return True
    return False


def _short(buf: bytes | bytearray, offset: int, end: int, final: bool, what: str) -> DecodeResult:
    inner = _later_magic(buf, offset, end)
    if inner >= 0:
        return _reject("magic_inside_packet", f"magic word at +{inner - offset} cuts the {what} short")
    if final:
        return _reject("truncated", f"stream ends inside the {what}")
    return _NEED_MORE


def _decode_as(buf: bytes | bytearray, offset: int, end: int, final: bool, fmt: HeaderFormat,
               chirp: ChirpParams | None) -> DecodeResult:
    hsize = fmt.size
    if end - offset < hsize:
        return _short(buf, offset, end, final, "header")
    hdr = FrameHeader.from_bytes(buf, offset, fmt)
    total = hdr.total_packet_len
    if total < hsize or total > MAX_PACKET_LEN:
        return _reject("bad_length", f"totalPacketLen {total} with a {hsize}-byte header")
    pkt_end = offset + total
    if pkt_end > end:
        return _short(buf, offset, end, final, f"{total}-byte packet")
    # a magic word *starting* before pkt_end may run up to 7 bytes past it
    inner = _later_magic(buf, offset, min(end, pkt_end + len(MAGIC) - 1))
    if inner >= 0:
        return _reject("magic_inside_packet", f"magic word at +{inner - offset} inside a {total}-byte packet")
    if not final and end < pkt_end + len(MAGIC) - 1 and _magic_prefix_at_tail(buf, max(offset + 8, end - 7), end):
        return _NEED_MORE  # the last bytes may begin a magic word that starts inside the packet

    major = version_major(hdr.version)
    registry = PC3D_TLVS if fmt is HeaderFormat.H48 else OOB_TLVS
    tlv_incl_header = fmt is HeaderFormat.H48
    pos = offset + hsize
    tlvs: list[TlvMessage] = []
    malformed: list[int] = []
    for k in range(hdr.num_tlvs):
        if pos + 8 > pkt_end:
            return _reject("tlv_out_of_bounds", f"TLV {k + 1}/{hdr.num_tlvs} header past the packet end")
        ttype, length = _TLV_HDR.unpack_from(buf, pos)
        if tlv_incl_header:
            if length < 8:
                return _reject("bad_tlv_length", f"TLV {k + 1} type {ttype}: length {length} < 8 "
                                                 "(48-B format lengths include the TLV header)")
            length -= 8
        start = pos + 8
        stop = start + length
        if stop > pkt_end:
            return _reject("tlv_out_of_bounds",
                           f"TLV {k + 1}/{hdr.num_tlvs} type {ttype}: {length} B run past the packet end")
        if isinstance(buf, bytes):
            payload = buf[start:stop]
        else:  # one copy into immutable bytes (the caller's bytearray may be resized later)
            with memoryview(buf) as mv:
                payload = bytes(mv[start:stop])
        try:
            if ttype == 1 and fmt is not HeaderFormat.H48:
                msg: TlvMessage = (DetectedPoints if major >= 3 else DetectedPointsQ).from_bytes(payload)
            else:
                cls = registry.get(ttype)
                msg = cls.from_bytes(payload) if cls is not None else RawTlv(ttype, payload)
        except DecodeError as exc:
            if ttype in (_PC3D_POINT_TLVS if fmt is HeaderFormat.H48 else _POINT_TLVS):
                return _reject("bad_tlv_payload", str(exc))
            # a side TLV (profile, heat map, stats, tracks) of an unexpected size costs only
            # itself: kept raw and counted, the frame's points stand
            msg = RawTlv(ttype, payload)
            malformed.append(ttype)
        tlvs.append(msg)
        pos = stop

    pad = pkt_end - pos
    if fmt is HeaderFormat.H48:
        if pad:
            return _reject("padding", f"{pad} bytes after the last TLV (48-B format is unpadded)")
    elif pad >= SEGMENT or (major >= 2 and total % SEGMENT):
        return _reject("padding", f"{pad} bytes after the last TLV in a {total}-byte packet")

    with np.errstate(all="ignore"):  # corrupt units may overflow: caught as non-finite below
        points, why = _points(hdr, major, tlvs, chirp)
    if why:
        return _reject("point_count", why)
    if not np.isfinite(points).all():
        return _reject("bad_tlv_payload", "point values are not finite (NaN/inf on the wire)")
    pkt = TiPacket(header=hdr, tlvs=tuple(tlvs), points=points, offset=offset, length=total,
                   malformed_tlvs=tuple(malformed))
    return DecodeResult(OK, packet=pkt, length=total)


def _snr_from_side_info(tlvs: list[TlvMessage], n: int) -> tuple[np.ndarray | None, str]:
    for t in tlvs:
        if isinstance(t, SideInfo):
            if len(t.info) != n:
                return None, f"TLV 7 has {len(t.info)} entries for {n} points"
            return t.snr_db(), ""
    return np.zeros(n, np.float32), ""


def _points(hdr: FrameHeader, major: int, tlvs: list[TlvMessage],
            chirp: ChirpParams | None) -> tuple[np.ndarray, str]:
    for t in tlvs:
        if isinstance(t, DetectedPoints):
            n = len(t.points)
            if major >= 3 and n != hdr.num_detected_obj:
                return _EMPTY5, f"TLV 1 holds {n} points, header numDetectedObj {hdr.num_detected_obj}"
            snr, why = _snr_from_side_info(tlvs, n)
            if why:
                return _EMPTY5, why
            out = np.empty((n, 5), np.float32)
            out[:, :4] = t.points.view(np.float32).reshape(n, 4) if n else np.zeros((0, 4), np.float32)
            out[:, 4] = snr
            return out, ""
        if isinstance(t, DetectedPointsQ):
            n = len(t.objects)
            if n != hdr.num_detected_obj:
                return _EMPTY5, f"TLV 1 holds {n} objects, header numDetectedObj {hdr.num_detected_obj}"
            snr, why = _snr_from_side_info(tlvs, n)
            if why:
                return _EMPTY5, why
            out = np.empty((n, 5), np.float32)
            out[:, :3] = t.xyz_m()
            out[:, 3] = doppler_from_index(t.objects["doppler_idx"], chirp)
            out[:, 4] = snr
            return out, ""
        if isinstance(t, ExtDetectedPoints):
            p, (xyz_u, dop_u, snr_u, _) = t.points, t.units
            out = np.empty((len(p), 5), np.float32)
            out[:, 0] = p["x"] * np.float32(xyz_u)
            out[:, 1] = p["y"] * np.float32(xyz_u)
            out[:, 2] = p["z"] * np.float32(xyz_u)
            out[:, 3] = p["doppler"] * np.float32(dop_u)
            out[:, 4] = p["snr"] * np.float32(snr_u)
            return out, ""
        if isinstance(t, CompressedPoints):
            return spherical_to_points(t), ""
    return _EMPTY5, ""


def doppler_from_index(doppler_idx: np.ndarray, chirp: ChirpParams | None) -> np.ndarray:
    """Signed Doppler bins -> m/s with the cfg's resolution (0.0 without a cfg)."""
    if chirp is None:
        return np.zeros(len(doppler_idx), np.float32)
    idx = doppler_idx.astype(np.int32)
    nd = int(chirp.num_doppler_bins)
    idx = np.where(idx >= nd // 2, idx - nd, idx)
    return (idx * chirp.doppler_resolution_mps).astype(np.float32)


def spherical_to_points(t: CompressedPoints) -> np.ndarray:
    """Compressed spherical points -> float32 (N, 5) mmatch points (see module doc)."""
    with np.errstate(all="ignore"):  # ratio 0 -> floor; absurd units -> non-finite values
        el_u, az_u, dop_u, r_u, snr_u = (np.float32(u) for u in t.units)
        p = t.points
        el = p["elevation"] * el_u
        az = p["azimuth"] * az_u
        r = p["range"] * r_u
        rc = r * np.cos(el)
        out = np.empty((len(p), 5), np.float32)
        out[:, 0] = rc * np.sin(az)
        out[:, 1] = rc * np.cos(az)
        out[:, 2] = r * np.sin(el)
        out[:, 3] = p["doppler"] * dop_u
        ratio = p["snr"] * snr_u
        out[:, 4] = np.maximum(np.float32(10.0) * np.log10(ratio), np.float32(SNR_FLOOR_DB))
    return out


__all__ = ["decode_frame", "DecodeResult", "TiPacket", "REASONS", "OK", "NEED_MORE", "REJECT",
           "POINT_F32", "doppler_from_index", "spherical_to_points"]
