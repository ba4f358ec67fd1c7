"""`mmatch bench` suite "uart": throughput of the TI streaming reader.

A points-heavy SDK 3.x stream (300-1000 points per frame with side info, written by the TLV
writer) is fed to `TlvReader` in 64 KiB pieces, as a capture replay would; the UART itself
delivers 0.09 MB/s (921600 baud), the headroom is for replaying long field logs.
"""

from __future__ import annotations

import time

import numpy as np

from mmatch.drivers.ti.reader import TlvReader
from mmatch.drivers.ti.writer import encode_frame


def _stream(n_frames: int, fmt: str, seed: int = 0) -> tuple[bytes, int]:
    rng = np.random.default_rng(seed)
    chunks, points = [], 0
    for k in range(n_frames):
        n = int(rng.integers(300, 1001))
        p = np.empty((n, 5), np.float32)
        p[:, 0] = rng.uniform(-40, 40, n)
        p[:, 1] = rng.uniform(1, 100, n)
        p[:, 2] = rng.uniform(-3, 3, n)
        p[:, 3] = rng.uniform(-30, 30, n)
        p[:, 4] = rng.uniform(5, 40, n)
        chunks.append(encode_frame(p, k + 1, fmt))
        points += n
    return b"".join(chunks), points


def _throughput(data: bytes, repeats: int, chunk: int = 65536) -> tuple[float, int]:
    best = float("inf")
    frames = 0
    for _ in range(repeats):
        reader = TlvReader(on_error="skip")
        t0 = time.perf_counter()
        for k in range(0, len(data), chunk):
            for pkt in reader.feed(data[k:k + chunk]):
                pkt.radar_frame()  # what a consumer receives: mmatch RadarFrame
        for pkt in reader.finish():
            pkt.radar_frame()
        best = min(best, time.perf_counter() - t0)
        frames = reader.stats.frames
    return best, frames


def run(quick: bool = False) -> dict:
    """Reader MB/s and frames/s (best of a few runs) on points-heavy streams, up to
    `RadarFrame`s; "sdk3" is the issue's target stream (>= 50 MB/s), "pc3d" the compressed
    spherical format (more points per byte, so fewer MB/s for the same frame rate)."""
    n_frames, repeats = (150, 2) if quick else (1500, 5)
    out: dict[str, float] = {}
    for fmt, key in (("sdk3", ""), ("pc3d", "_pc3d")):
        data, points = _stream(n_frames if fmt == "sdk3" else n_frames // 2, fmt)
        dt, frames = _throughput(data, repeats)
        out[f"reader_mb_per_s{key}"] = round(len(data) / dt / 1e6, 1)
        out[f"reader_frames_per_s{key}"] = round(frames / dt, 0)
        out[f"points_per_frame_mean{key}"] = round(points / max(frames, 1), 1)
        out[f"stream_mb{key}"] = round(len(data) / 1e6, 2)
        if fmt == "sdk3":  # serial-sized reads (4 KiB), as a live port or paced replay feeds it
            dt4, _ = _throughput(data, repeats, chunk=4096)
            out["reader_mb_per_s_4k_reads"] = round(len(data) / dt4 / 1e6, 1)
    out["uart_line_mb_per_s"] = round(921600 / 10 / 1e6, 3)
    return out
