"""Byte fixtures for the TI UART tests, all made with the TLV writer (nothing on disk).

`make_points` gives deterministic mmatch points; `all_tlv_messages` one message of every
supported TLV type; `named_fixtures` the small named error-path streams (the pyubx2 style:
one per corrupt case), each with what a reader must report for it.
"""

from __future__ import annotations

import struct

import numpy as np

from mmatch.drivers.ti.header import MAGIC
from mmatch.drivers.ti.tlv import (
    CMPLX16, COMPRESSED_POINT, EXT_POINT, SIDE_INFO, TARGET_2D, TARGET_3D, TARGET_HEIGHT,
    AzimuthElevationStaticHeatMap, AzimuthStaticHeatMap, CompressedPoints, ExtDetectedPoints,
    NoiseProfile, Pc3dTargetIndex, Pc3dTargetList, PresenceIndication, RangeDopplerHeatMap,
    RangeProfile, RawTlv, SideInfo, Stats, TargetHeight, TargetIndex, TargetList,
    TemperatureStats)
from mmatch.drivers.ti.writer import encode_frame


def make_points(n: int, seed: int = 0, max_range: float = 60.0) -> np.ndarray:
    """float32 (n, 5) points in front of the radar: x, y, z (m), doppler (m/s), snr (dB)."""
    rng = np.random.default_rng(seed)
    p = np.zeros((n, 5), np.float32)
    r = rng.uniform(1.0, max_range, n)
    az = rng.uniform(-1.0, 1.0, n)
    el = rng.uniform(-0.2, 0.2, n)
    p[:, 0] = r * np.cos(el) * np.sin(az)
    p[:, 1] = r * np.cos(el) * np.cos(az)
    p[:, 2] = r * np.sin(el)
    p[:, 3] = rng.uniform(-25.0, 25.0, n)
    p[:, 4] = rng.uniform(3.0, 40.0, n)
    return p


def _rand(dtype: np.dtype, n: int, rng: np.random.Generator) -> np.ndarray:
    raw = rng.integers(0, 256, n * dtype.itemsize, dtype=np.uint8).tobytes()
    a = np.frombuffer(raw, dtype=dtype).copy()
    for name in dtype.names or ():
        if a[name].dtype.kind == "f":  # keep floats finite (random bits may be NaN)
            a[name] = rng.normal(size=a[name].shape).astype(np.float32)
    return a


def all_tlv_messages(seed: int = 1) -> dict[str, list]:
    """Messages of every supported TLV type, by the format family that carries them."""
    rng = np.random.default_rng(seed)
    oob = [
        RangeProfile(rng.integers(0, 65535, 64).astype("<u2")),
        NoiseProfile(rng.integers(0, 65535, 64).astype("<u2")),
        AzimuthStaticHeatMap(_rand(CMPLX16, 64 * 8, rng)),
        RangeDopplerHeatMap(rng.integers(0, 65535, 64 * 16).astype("<u2")),
        Stats(1200, 300, 48000, 12, 35, 20),
        AzimuthElevationStaticHeatMap(_rand(CMPLX16, 64 * 12, rng)),
        TemperatureStats(0, 123456, (41, 42, 43, 44, 50, 51, 52, 39, 45, 46)),
        ExtDetectedPoints((0.00390625, 0.01, 0.1, 0.1), 5, 2, _rand(EXT_POINT, 7, rng)),
        TargetList(_rand(TARGET_3D, 3, rng)),
        TargetIndex(rng.integers(0, 256, 11).astype(np.uint8)),
        TargetHeight(_rand(TARGET_HEIGHT, 3, rng)),
        CompressedPoints((0.01, 0.01, 0.00028, 0.00025, 0.04), _rand(COMPRESSED_POINT, 9, rng)),
        PresenceIndication(1),
        RawTlv(10, bytes(rng.integers(0, 256, 13, dtype=np.uint8))),
        RawTlv(555, b""),
    ]
    pc3d = [
        Pc3dTargetList(_rand(TARGET_3D, 2, rng)),
        Pc3dTargetIndex(rng.integers(0, 256, 9).astype(np.uint8)),
        RawTlv(12, struct.pack("<I", 7)),
    ]
    return {"oob": oob, "pc3d": pc3d, "target2d": [TargetList(_rand(TARGET_2D, 1, rng))],
            "side_info": [SideInfo(_rand(SIDE_INFO, 4, rng))]}


def pc3d_header_frame(frame_number: int, points: np.ndarray) -> bytes:
    return encode_frame(points, frame_number, "pc3d",
                        header_fields=dict(chirp_processing_margin=51, frame_processing_margin=7,
                                           track_process_time=325, uart_sent_time=5188))


def named_fixtures() -> dict[str, tuple[bytes, dict]]:
    """name -> (stream, expectations): "frames" (frame numbers out, in order),
    "rejected" (reason -> count), "skipped" (bytes skipped), optional "restarts"."""
    p = [make_points(n, seed=n) for n in (5, 8, 3, 6)]
    f = [encode_frame(p[k], 10 + k, "sdk3") for k in range(4)]
    out: dict[str, tuple[bytes, dict]] = {}
    out["clean.bin"] = (b"".join(f), {"frames": [10, 11, 12, 13], "rejected": {}, "skipped": 0})
    junk = bytes(range(256)) * 3 + b"\x02\x01\x04\x03"
    out["leading_junk.bin"] = (junk + b"".join(f), {"frames": [10, 11, 12, 13], "rejected": {},
                                                    "skipped": len(junk)})
    cut = f[1][:50] + f[1][51:]
    out["dropped_byte.bin"] = (f[0] + cut + f[2] + f[3], {
        "frames": [10, 12, 13], "rejected": {"magic_inside_packet": 1}, "skipped": len(cut)})
    out["truncated_end.bin"] = (f[0] + f[1] + f[2][:70], {
        "frames": [10, 11], "rejected": {"truncated": 1}, "skipped": 70})
    out["cut_header.bin"] = (f[0] + f[1][:25] + f[2], {
        "frames": [10, 12], "rejected": {"magic_inside_packet": 1}, "skipped": 25})
    out["truncated_header.bin"] = (f[0] + f[1][:25], {
        "frames": [10], "rejected": {"truncated": 1}, "skipped": 25})
    out["magic_only_at_end.bin"] = (f[0] + MAGIC, {"frames": [10], "rejected": {"truncated": 1},
                                                   "skipped": 8})
    inner = bytearray(f[1])
    inner[60:68] = MAGIC
    out["second_magic_inside.bin"] = (f[0] + bytes(inner) + f[2], {
        "frames": [10, 12], "rejected": {"magic_inside_packet": 1, "bad_length": 1},
        "skipped": len(inner)})
    restart = [encode_frame(p[k], fn, "sdk3") for k, fn in enumerate((500, 501, 1, 2))]
    out["sensor_restart.bin"] = (b"".join(restart), {"frames": [500, 501, 1, 2], "rejected": {},
                                                     "skipped": 0, "restarts": 1})
    bad_len = bytearray(f[1])
    struct.pack_into("<I", bad_len, 40 + 4, 16 * 8 + 4)  # TLV 1 length 4 B over its real size
    out["bad_tlv_length.bin"] = (f[0] + bytes(bad_len) + f[2], {
        "frames": [10, 12], "rejected": {"bad_tlv_payload": 1}, "skipped": len(bad_len)})
    over = bytearray(f[1])
    struct.pack_into("<I", over, 40 + 4, 100000)
    out["tlv_out_of_bounds.bin"] = (f[0] + bytes(over) + f[2], {
        "frames": [10, 12], "rejected": {"tlv_out_of_bounds": 1}, "skipped": len(over)})
    padded = f[1] + bytes(32)
    padded = padded[:12] + struct.pack("<I", len(padded)) + padded[16:]
    out["padding_32.bin"] = (f[0] + padded + f[2], {
        "frames": [10, 12], "rejected": {"padding": 1}, "skipped": len(padded)})
    count = bytearray(f[1])
    struct.pack_into("<I", count, 28, 9)  # numDetectedObj 9 but TLV 1 holds 8
    out["point_count.bin"] = (f[0] + bytes(count) + f[2], {
        "frames": [10, 12], "rejected": {"point_count": 1}, "skipped": len(count)})
    huge = bytearray(f[1])
    struct.pack_into("<I", huge, 12, 0x7FFFFFFF)
    out["bad_total_length.bin"] = (f[0] + bytes(huge) + f[2], {
        "frames": [10, 12], "rejected": {"bad_length": 1}, "skipped": len(huge)})
    g = [pc3d_header_frame(20 + k, p[k]) for k in range(3)]
    bad_cks = bytearray(g[1])
    bad_cks[24] ^= 0x01  # subFrameNumber bit: only the checksum can tell
    out["pc3d_bad_checksum.bin"] = (g[0] + bytes(bad_cks) + g[2], {
        "frames": [20, 22], "rejected": {"header_checksum": 1}, "skipped": len(bad_cks)})
    return out


def golden_sdk3_frame() -> bytes:
    """One SDK 3.x frame built by hand with struct (independent of the writer): frame 7,
    2 points, TLV 1 + TLV 7, padded to 32 bytes."""
    pts = struct.pack("<8f", 1.0, 2.0, 0.5, -1.5, -3.0, 40.0, 0.0, 12.25)
    side = struct.pack("<4h", 125, 30, -5, 31)
    body = struct.pack("<2I", 1, 32) + pts + struct.pack("<2I", 7, 8) + side
    total = 40 + len(body)
    total += (-total) % 32
    hdr = MAGIC + struct.pack("<8I", 0x03050004, total, 0xA1843, 7, 0, 2, 2, 0)
    return (hdr + body).ljust(total, b"\0")


def golden_pc3d_frame() -> bytes:
    """One 48-byte-header people-counting frame by hand: TLV 6 with 1 point, lengths that
    include the TLV header, checksum over the 24 header words."""
    units = struct.pack("<5f", 0.01, 0.01, 0.00028, 0.00025, 0.04)
    point = struct.pack("<2bh2H", 5, -10, 1000, 8000, 500)
    body = struct.pack("<2I", 6, 8 + 20 + 8) + units + point
    total = 48 + len(body)
    words = MAGIC + struct.pack("<9IH", 0x03050004, total, 0xA6843, 45, 0, 51, 7, 325, 5188, 1)
    s = sum(struct.unpack("<23H", words))
    while s > 0xFFFF:
        s = (s & 0xFFFF) + (s >> 16)
    return words + struct.pack("<H", ~s & 0xFFFF) + body
