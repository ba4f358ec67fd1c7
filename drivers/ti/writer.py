"""TLV writer: mmatch points -> byte-exact TI UART packets (the test fixtures and the
simulator's synthetic serial streams come from here).

    encode_frame(points, frame_number, fmt="sdk3", **options) -> bytes
    encode_stream(point_arrays, fmt="sdk3", first_frame=1, **options) -> bytes
    encode_packet(tlvs, frame_number, fmt="sdk3", num_detected_obj=0, ...) -> bytes
    expected_points(points, fmt="sdk3", **options) -> float32 (N, 5)   # what the decoder returns

Formats (`FORMATS`):

| fmt | header | points as | padding |
|---|---|---|---|
| "sdk3" | 40 B, v3.5.0.4, xWR1843 | TLV 1 float32 x,y,z,v + TLV 7 snr/noise (0.1 dB) | 32 B |
| "sdk2" | 40 B, v2.1.0.4, xWR1642 | TLV 1 Q-format (no SNR on the wire) | 32 B |
| "sdk1" | 40 B, v1.2.0.0, xWR1642 | TLV 1 Q-format | 32 B |
| "xwr14xx" | 36 B, v2.1.0.4, xWR1443 | TLV 1 Q-format | 32 B |
| "toolbox" | 40 B, v3.6.0.0, xWR6843 | TLV 1020 compressed spherical | 32 B |
| "pc3d" | 48 B with checksum, v3.5.0.4, xWR6843 | TLV 6 compressed spherical, TLV lengths include the 8-B TLV header | none |

Points are float32 (N, 5) x, y, z (m), doppler (m/s), snr (dB) in the radar frame. What the
wire cannot hold is quantised (Q-format xyz, 0.1-dB SNR, compressed units) or dropped (SNR in
Q-format); `expected_points` gives exactly what `decode_frame` will return.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mmatch.drivers.ti.decoder import SEGMENT, doppler_from_index, spherical_to_points
from mmatch.drivers.ti.header import FrameHeader, HeaderFormat
from mmatch.drivers.ti.tlv import (
    COMPRESSED_POINT, POINT_F32, POINT_Q, SIDE_INFO, CompressedPoints, DetectedPoints,
    DetectedPointsQ, Pc3dCompressedPoints, SideInfo, TlvMessage)
from mmatch.errors import MMatchError

if TYPE_CHECKING:
    from mmatch.drivers.ti.cfg import ChirpParams


class EncodeError(MMatchError, ValueError):
    """Points or options that cannot be written in the requested format."""


@dataclass(frozen=True)
class FormatSpec:
    header: HeaderFormat
    version: int
    platform: int
    points: str  # "float", "q", "compressed"
    side_info: bool  # TLV 7 written by default


FORMATS: dict[str, FormatSpec] = {
    "sdk3": FormatSpec(HeaderFormat.H40, 0x03050004, 0xA1843, "float", True),
    "sdk2": FormatSpec(HeaderFormat.H40, 0x02010004, 0xA1642, "q", False),
    "sdk1": FormatSpec(HeaderFormat.H40, 0x01020000, 0xA1642, "q", False),
    "xwr14xx": FormatSpec(HeaderFormat.H36, 0x02010004, 0xA1443, "q", False),
    "toolbox": FormatSpec(HeaderFormat.H40, 0x03060000, 0xA6843, "compressed", False),
    "pc3d": FormatSpec(HeaderFormat.H48, 0x03050004, 0xA6843, "compressed", False),
}

DEFAULT_UNITS: tuple[float, float, float, float, float] = (0.01, 0.01, 0.002, 0.0025, 0.25)
"""Compressed point units (elevation rad, azimuth rad, doppler m/s, range m, snr ratio) for
vehicles: +-72 deg, +-65 m/s, 163 m, SNR up to 42 dB."""

TI_PC3D_UNITS: tuple[float, float, float, float, float] = (0.01, 0.01, 0.00028, 0.00025, 0.04)
"""The units TI's 3D People Counting firmware sends (indoor: 16 m, +-9 m/s)."""


def _spec(fmt: str) -> FormatSpec:
    try:
        return FORMATS[fmt]
    except KeyError:
        raise EncodeError(f"unknown TLV format {fmt!r}; one of {sorted(FORMATS)}") from None


def _check_points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float32)
    if p.ndim != 2 or p.shape[1] != 5:
        raise EncodeError(f"points must be (N, 5) x, y, z, doppler, snr; got shape {p.shape}")
    if not np.isfinite(p).all():
        raise EncodeError("points contain NaN or inf")
    return p


def auto_q_format(points: np.ndarray, max_q: int = 9) -> int:
    """Largest Q (<= max_q) with every |x|, |y|, |z| * 2**Q within int16."""
    m = float(np.abs(points[:, :3]).max()) if len(points) else 0.0
    q = max_q
    while q > 0 and m * (1 << q) > 32767:
        q -= 1
    return q


def _q_objects(p: np.ndarray, q: int, chirp: ChirpParams | None) -> np.ndarray:
    objs = np.zeros(len(p), POINT_Q)
    scale = np.float32(1 << q)
    for i, name in enumerate("xyz"):
        objs[name] = np.clip(np.rint(p[:, i] * scale), -32768, 32767).astype(np.int16)
    if chirp is not None:
        rng = np.linalg.norm(p[:, :3], axis=1)
        objs["range_idx"] = np.clip(np.rint(rng / chirp.range_idx_to_m), 0, 65535).astype(np.uint16)
        half = chirp.num_doppler_bins // 2
        objs["doppler_idx"] = np.clip(np.rint(p[:, 3] / chirp.doppler_resolution_mps), -half, half - 1)
    return objs


def _compressed(p: np.ndarray, units: Sequence[float]) -> np.ndarray:
    el_u, az_u, dop_u, r_u, snr_u = (float(u) for u in units)
    x, y, z = (p[:, i].astype(np.float64) for i in range(3))
    r = np.sqrt(x * x + y * y + z * z)
    az = np.arctan2(x, y)
    el = np.arctan2(z, np.hypot(x, y))
    c = np.zeros(len(p), COMPRESSED_POINT)
    c["elevation"] = np.clip(np.rint(el / el_u), -128, 127)
    c["azimuth"] = np.clip(np.rint(az / az_u), -128, 127)
    c["doppler"] = np.clip(np.rint(p[:, 3] / dop_u), -32768, 32767)
    c["range"] = np.clip(np.rint(r / r_u), 0, 65535)
    c["snr"] = np.clip(np.rint(10.0 ** (p[:, 4].astype(np.float64) / 10.0) / snr_u), 0, 65535)
    return c


def point_tlvs(points: np.ndarray, fmt: str = "sdk3", *, side_info: bool | None = None,
               noise_db: float | np.ndarray = 0.0, empty_tlv1: str = "omit",
               q_format: int | None = None, chirp: ChirpParams | None = None,
               units: Sequence[float] = DEFAULT_UNITS) -> list[TlvMessage]:
    """The TLV messages that carry `points` in format `fmt` (see `encode_frame`)."""
    spec = _spec(fmt)
    p = _check_points(points)
    n = len(p)
    side = spec.side_info if side_info is None else side_info
    out: list[TlvMessage] = []
    if spec.points == "compressed":
        cls = Pc3dCompressedPoints if spec.header is HeaderFormat.H48 else CompressedPoints
        return [cls(tuple(float(u) for u in units), _compressed(p, units))]
    if n == 0 and empty_tlv1 == "omit":
        return out
    if n == 0 and empty_tlv1 == "zero_length":  # SDK 3.3: TLV 1 of length 0, and no TLV 7
        return [DetectedPoints(np.zeros(0, POINT_F32))] if spec.points == "float" else \
            [DetectedPointsQ(0, np.zeros(0, POINT_Q))]
    if empty_tlv1 not in ("omit", "zero_length"):
        raise EncodeError(f"empty_tlv1 must be 'omit' or 'zero_length', not {empty_tlv1!r}")
    if spec.points == "float":
        pts = np.zeros(n, POINT_F32)
        for i, name in enumerate(("x", "y", "z", "v")):
            pts[name] = p[:, i]
        out.append(DetectedPoints(pts))
    else:
        q = auto_q_format(p) if q_format is None else int(q_format)
        if not 0 <= q <= 15:
            raise EncodeError(f"q_format {q} outside 0..15")
        out.append(DetectedPointsQ(q, _q_objects(p, q, chirp)))
    if side:
        info = np.zeros(n, SIDE_INFO)
        info["snr"] = np.clip(np.rint(p[:, 4] * 10.0), -32768, 32767)
        info["noise"] = np.clip(np.rint(np.broadcast_to(np.asarray(noise_db, np.float64), (n,)) * 10.0),
                                -32768, 32767)
        out.append(SideInfo(info))
    return out


def encode_packet(tlvs: Sequence[TlvMessage], frame_number: int, fmt: str = "sdk3", *,
                  num_detected_obj: int = 0, version: int | None = None,
                  platform: int | None = None, time_cpu_cycles: int = 0,
                  sub_frame_number: int = 0, header_fields: dict | None = None) -> bytes:
    """Header + `tlvs` (in order) + padding, byte-exact for format `fmt`.

    TLV lengths are payload bytes, except in "pc3d" where they include the 8-byte TLV
    header; packets are padded with zeros to a multiple of 32 bytes except in "pc3d".
    header_fields: extra FrameHeader fields (e.g. track_process_time for "pc3d").
    """
    spec = _spec(fmt)
    incl = spec.header is HeaderFormat.H48
    body = bytearray()
    for t in tlvs:
        payload = t.to_bytes()
        body += struct.pack("<2I", int(t.type), len(payload) + (8 if incl else 0))
        body += payload
    total = spec.header.size + len(body)
    if not incl:
        total = -(-total // SEGMENT) * SEGMENT
    hdr = FrameHeader(fmt=spec.header, version=spec.version if version is None else version,
                      total_packet_len=total, platform=spec.platform if platform is None else platform,
                      frame_number=int(frame_number) & 0xFFFFFFFF, num_tlvs=len(tlvs),
                      time_cpu_cycles=time_cpu_cycles, num_detected_obj=num_detected_obj,
                      sub_frame_number=sub_frame_number, **(header_fields or {}))
    out = hdr.to_bytes() + bytes(body)
    return out + bytes(total - len(out))


def encode_frame(points: np.ndarray, frame_number: int, fmt: str = "sdk3", *,
                 side_info: bool | None = None, noise_db: float | np.ndarray = 0.0,
                 empty_tlv1: str = "omit", q_format: int | None = None,
                 chirp: ChirpParams | None = None, units: Sequence[float] = DEFAULT_UNITS,
                 extra_tlvs: Sequence[TlvMessage] = (), version: int | None = None,
                 platform: int | None = None, time_cpu_cycles: int = 0,
                 sub_frame_number: int = 0, header_fields: dict | None = None) -> bytes:
    """One UART packet carrying `points` (float32 (N, 5) x, y, z, doppler, snr dB).

    fmt: a key of `FORMATS`. side_info: write TLV 7 (default: "sdk3" yes, others no).
    noise_db: TLV 7 noise per point or scalar (dB). empty_tlv1: with no points, "omit" TLV 1
    (TI doxygen) or send it with "zero_length" and no TLV 7 (real SDK 3.3).
    q_format: Q of Q-format xyz (default: largest <= 9 that fits). chirp: cfg parameters
    for Q-format rangeIdx/dopplerIdx (without it both are 0 and doppler is lost).
    units: compressed-point units for "toolbox"/"pc3d". extra_tlvs: more messages after the
    point TLVs. version/platform/time_cpu_cycles/sub_frame_number/header_fields: header.
    """
    spec = _spec(fmt)
    p = _check_points(points)
    tlvs = point_tlvs(p, fmt, side_info=side_info, noise_db=noise_db, empty_tlv1=empty_tlv1,
                      q_format=q_format, chirp=chirp, units=units) + list(extra_tlvs)
    nobj = 0 if spec.header is HeaderFormat.H48 else len(p)
    return encode_packet(tlvs, frame_number, fmt, num_detected_obj=nobj, version=version,
                         platform=platform, time_cpu_cycles=time_cpu_cycles,
                         sub_frame_number=sub_frame_number, header_fields=header_fields)


def encode_stream(point_arrays: Iterable[np.ndarray], fmt: str = "sdk3", first_frame: int = 1,
                  **options) -> bytes:
    """Concatenated packets of consecutive frame numbers (options as for `encode_frame`)."""
    return b"".join(encode_frame(p, first_frame + i, fmt, **options)
                    for i, p in enumerate(point_arrays))


def expected_points(points: np.ndarray, fmt: str = "sdk3", *, side_info: bool | None = None,
                    q_format: int | None = None, chirp: ChirpParams | None = None,
                    units: Sequence[float] = DEFAULT_UNITS) -> np.ndarray:
    """What `decode_frame` returns for `encode_frame(points, ..., fmt)` (float32 (N, 5))."""
    spec = _spec(fmt)
    p = _check_points(points)
    side = spec.side_info if side_info is None else side_info
    tlvs = point_tlvs(p, fmt, side_info=side, q_format=q_format, chirp=chirp, units=units)
    if not tlvs:
        return np.zeros((0, 5), np.float32)
    head = tlvs[0]
    if isinstance(head, CompressedPoints):
        return spherical_to_points(head)
    out = np.zeros((len(p), 5), np.float32)
    if isinstance(head, DetectedPoints):
        out[:, :4] = p[:, :4]
    elif isinstance(head, DetectedPointsQ):
        out[:, :3] = head.xyz_m()
        out[:, 3] = doppler_from_index(head.objects["doppler_idx"], chirp)
    if side:
        out[:, 4] = tlvs[1].snr_db()  # type: ignore[attr-defined]
    return out
