"""Speed of the vehicle service's own parts (for `mmatch bench`; suite name "edge").

recorder: field-log writes per second (a 300-point cloud + 600 raw UART bytes per frame,
zstd chunks); reader: log messages read back per second; zenoh: round trip of a 4 KiB
shared frame between two sessions over TCP 127.0.0.1 (median, p99 ms); auth: Ed25519 signing
of a typical shared frame (12 vehicles, 60 points, 300 background points) plus every
receiver check including the signature (ms per frame, median and p99; target <= 0.2), and
how fast a forgery is refused (frames/s).
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


class _KeyIdOnly:
    """Names the key in the header; the bench signs the bytes itself."""

    def __init__(self, key_id: bytes) -> None:
        self.key_id = key_id

    def sign(self, message: bytes) -> bytes:
        return bytes(64)


def bench_auth(frames: int) -> dict:
    """Sign + verify per shared frame, through the same Verifier the Ego uses."""
    from mmatch import codec
    from mmatch.edge import auth
    from mmatch.shared import SharedFrame

    rng = np.random.default_rng(0)
    V, K, B = 12, 60, 300
    frame = SharedFrame(
        sender="cav1", seq=0, stamp=0.0, radar_height=1.0, ego_velocity=np.array([1.0, 8.0]),
        vehicle_points=np.c_[rng.uniform(-30, 30, (K, 3)), rng.uniform(-5, 5, (K, 1)),
                             rng.uniform(5, 30, (K, 1))].astype(np.float32),
        vehicle_index=np.sort(rng.integers(0, V, K)).astype(np.int32),
        vehicle_boxes=np.tile(np.array([[100, 200, 180, 260, 0.8, 25.0]], np.float32), (V, 1)),
        vehicle_box_index=np.arange(V, dtype=np.int32),
        vehicle_centers=rng.uniform(-30, 30, (V, 2)).astype(np.float32),
        vehicle_features=np.full((V, 32), 1 / 16, np.float32),
        background=rng.uniform(-60, 60, (B, 3)).astype(np.float32))
    with tempfile.TemporaryDirectory() as d:
        pub = auth.generate_key(os.path.join(d, "cav1.key"))
        auth.generate_key(os.path.join(d, "mallory.key"))
        auth.write_trust(os.path.join(d, "trust.toml"), {"cav1": [pub]})
        signer = auth.Signer.from_file("cav1", os.path.join(d, "cav1.key"))
        now = 1000.0
        verifier = auth.Verifier(auth.TrustStore(os.path.join(d, "trust.toml")), ahead_s=0.05,
                                 behind_s=0.15, clock=lambda: now)
        sign_ms, verify_ms, checks_ms = [], [], []
        public = verifier.trust.lookup("cav1", signer.key_id)
        for i in range(frames):
            frame.seq, frame.stamp = i + 1, now
            # the CAV's encoding is not part of the cost: only the signature over its bytes
            signed = codec.split_signature(codec.encode(frame, _KeyIdOnly(signer.key_id)))[0]
            t0 = time.perf_counter()
            data = signed + signer.sign(signed)
            t1 = time.perf_counter()
            public.verify(data[-64:], signed)                        # the signature alone
            t2 = time.perf_counter()
            verifier.open_frame("cav1", data)                        # every check + decode
            t3 = time.perf_counter()
            sign_ms.append((t1 - t0) * 1e3)
            verify_ms.append((t2 - t1) * 1e3)
            checks_ms.append((t3 - t2) * 1e3)
        # forgeries with fresh seqs and stamps, signed by a key the trust file lacks but that
        # claims cav1's key id: each costs a signature check
        mallory = auth.Signer.from_file("cav1", os.path.join(d, "mallory.key"))
        mallory.key_id = signer.key_id
        forged = []
        for i in range(frames):
            frame.seq = frames + 1 + i
            forged.append(codec.encode(frame, mallory))
        t0 = time.perf_counter()
        for data in forged:
            try:
                verifier.open_frame("cav1", data)
            except auth.Rejected:
                pass
        t_forged = time.perf_counter() - t0
    total = np.asarray(sign_ms) + np.asarray(verify_ms)
    return {"auth_sign_ms_median": round(float(np.median(sign_ms)), 4),
            "auth_verify_ms_median": round(float(np.median(verify_ms)), 4),
            "auth_sign_verify_ms_median": round(float(np.median(total)), 4),
            "auth_sign_verify_ms_p99": round(float(np.percentile(total, 99)), 4),
            "auth_receiver_checks_ms_median": round(float(np.median(checks_ms)), 4),
            "auth_frame_bytes": len(data),
            "auth_forged_refused_per_s": round(frames / t_forged, 1)}


def run(quick: bool = False) -> dict:
    out = bench_auth(200 if quick else 3000)
    out.update(bench_recorder(200 if quick else 4000))
    out.update(bench_zenoh(30 if quick else 500))
    return out
