"""Speed of the vehicle service's own parts (for `mmatch bench`; suite name "edge").

recorder: field-log writes per second (a 300-point cloud + 600 raw UART bytes per frame,
zstd chunks); reader: log messages read back per second; zenoh: round trip of a 4 KiB
shared frame between two sessions over TCP 127.0.0.1 (median, p99 ms).
"""

from __future__ import annotations

import os
import socket
import tempfile
import threading
import time

import numpy as np


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_recorder(frames: int) -> dict:
    from mmatch.edge import logreader, logschema
    from mmatch.edge.config import LogSection
    from mmatch.edge.recorder import Recorder

    pts = np.random.default_rng(0).normal(size=(300, 5)).astype(np.float32)
    raw = os.urandom(600)
    with tempfile.TemporaryDirectory() as d:
        with Recorder(LogSection(dir=d, raw_floor_mb=0.0, floor_mb=0.0)) as rec:
            t0 = time.perf_counter()
            for i in range(frames):
                stamp = 1000.0 + 0.05 * i
                rec.write(logschema.POINTS, logschema.points_message(pts, stamp, "bench"), stamp=stamp)
                rec.write(logschema.RAW_UART, raw)
            t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        n = sum(1 for _ in logreader.read_messages(d))
        t_read = time.perf_counter() - t0
    return {"recorder_frames_per_s": round(frames / t_write, 1),
            "reader_messages_per_s": round(n / t_read, 1)}


def bench_zenoh(messages: int) -> dict:
    from mmatch.edge import keys
    from mmatch.edge.config import ZenohSection
    from mmatch.edge.transport import Transport

    ep = f"tcp/127.0.0.1:{_free_port()}"
    got = threading.Event()
    lat: list[float] = []
    with Transport(ZenohSection(listen=[ep])) as a, Transport(ZenohSection(connect=[ep])) as b:
        b.subscribe(keys.shared("bench"), "shared", lambda v, p: b.put(keys.fused("bench"), p))
        a.subscribe(keys.fused("bench"), "fused",
                    lambda v, p: (lat.append(time.perf_counter() - float(p[:20])), got.set()))
        a.wait_for_peers(5.0)
        payload = b"x" * 4096

        def ping() -> bool:
            got.clear()
            a.put(keys.shared("bench"), f"{time.perf_counter():<20.9f}".encode() + payload)
            return got.wait(1.0)

        # Subscriptions reach the other session a little after the link is up: warm up
        # until a round trip completes, so only the measured messages count as lost.
        deadline = time.monotonic() + 10.0
        while not ping() and time.monotonic() < deadline:
            pass
        for _ in range(20):
            ping()
        lat.clear()
        for _ in range(messages):
            ping()
    lat_ms = np.asarray(lat) * 1e3
    if len(lat_ms) == 0:
        return {"zenoh_rtt_ms_median": float("nan"), "zenoh_rtt_lost": messages}
    return {"zenoh_rtt_ms_median": round(float(np.median(lat_ms)), 3),
            "zenoh_rtt_ms_p99": round(float(np.percentile(lat_ms, 99)), 3),
            "zenoh_rtt_lost": messages - len(lat)}


def run(quick: bool = False) -> dict:
    out = bench_recorder(200 if quick else 4000)
    out.update(bench_zenoh(30 if quick else 500))
    return out
