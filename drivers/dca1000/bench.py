"""`mmatch bench` suite "dsp": DSP time per frame and fake-DCA1000 loopback throughput.

DSP frame: AWR2243 3 TX x 4 RX TDM-MIMO, 128 chirps per TX (= 128 Doppler bins, 384 chirps per
frame), 256 samples, 4-lane raw bytes -> points (raw_to_cube + RadarDsp.process), one core
(scipy.fft workers=1). Loopback: a fake DCA1000 in another process streams a bounded recording
(64 frames = 100 MB, at most 20 s) to a DataReceiver on 127.0.0.1, paced at the DCA1000's own
limit, Gigabit Ethernet line rate (`LOOPBACK_RATE_MB_S` = 125 MB/s); throughput is measured from
the first to the last frame, and every frame must arrive complete and byte-exact. The full run
also streams unpaced (`loopback_unpaced_*`: the receiver's capacity; the kernel may then drop).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import socket
import time

import numpy as np

log = logging.getLogger(__name__)

AWR2243_BENCH_CFG = """\
% AWR2243BOOST + DCA1000EVM, TDM-MIMO 3 TX x 4 RX, 128 loops (Doppler bins),
% 256 complex samples, 4-lane LVDS. Vehicle-grade: max range 102 m (0.445 m bins),
% max velocity +-20.3 m/s (0.317 m/s bins). TI CLI .cfg form, so the same parser
% (drivers/ti/cfg.py) drives the UART and DCA1000 paths.
sensorStop
flushCfg
dfeDataOutputMode 1
channelCfg 15 7 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 2 2 14 0 0 29 1 256 22000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 2
chirpCfg 2 2 0 0 0 0 0 4
frameCfg 0 2 128 8 50 1 0
lowPower 0 0
cfarCfg -1 0 2 8 4 3 0 15 1
cfarCfg -1 1 0 4 2 3 1 15 1
clutterRemoval -1 0
lvdsStreamCfg -1 0 1 0
sensorStart
"""

LOOPBACK_RATE_MB_S = 125.0
"""Gigabit Ethernet line rate, the most a real DCA1000 can send."""


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_dsp(frames: int) -> dict:
    from mmatch.drivers.ti.cfg import parse_cfg

    from .dsp import make_dsp
    from .layout import cube_to_raw, raw_to_cube
    from .synth import Target, synth_cube

    cfg = parse_cfg(AWR2243_BENCH_CFG, "<bench>")
    geom, dsp = make_dsp(cfg)
    targets = [
        Target(5.0, 0.0, 0.0),
        Target(22.0, 3.0, 20.0, 5.0),
        Target(40.0, -15.0, -30.0),
        Target(60.0, 18.0, 45.0),
        Target(12.0, -1.0, -10.0, -5.0),
    ]
    raw = cube_to_raw(synth_cube(cfg.chirp, geom, targets), geom)
    times = []
    npts = 0
    for _ in range(frames + 2):
        t0 = time.perf_counter()
        res = dsp.process(raw_to_cube(raw, geom))
        times.append(time.perf_counter() - t0)
        npts = len(res.points)
    t = np.asarray(times[2:]) * 1e3
    return {
        "dsp_frame_ms_median": round(float(np.median(t)), 3),
        "dsp_frame_ms_p90": round(float(np.percentile(t, 90)), 3),
        "dsp_frames": frames,
        "dsp_doppler_bins": geom.num_loops,
        "dsp_virtual_channels": geom.num_virtual,
        "dsp_samples": geom.num_samples,
        "dsp_points": npts,
        "dsp_targets": len(targets),
    }


def bench_loopback(
    frames: int,
    rate_mb_s: float | None = LOOPBACK_RATE_MB_S,
    timeout_s: float = 20.0,
    prefix: str = "loopback",
) -> dict:
    from .assembler import FrameAssembler
    from .control import Dca1000Control
    from .fake import serve_in_process
    from .receiver import DataReceiver

    frame_bytes = 384 * 4 * 256 * 4
    a = (
        np.random.default_rng(7)
        .integers(-2000, 2000, size=frame_bytes // 2, dtype=np.int16)
        .tobytes()
    )
    src = a + a[frame_bytes // 2 :] + a[: frame_bytes // 2]  # two distinct frames
    ctx = mp.get_context("spawn")
    cport = _free_udp_port()
    asm = FrameAssembler(frame_bytes, num_frames=frames)
    n = exact = 0
    first = last = None
    with DataReceiver(asm, host="127.0.0.1", port=0) as rx:
        ready = ctx.Event()
        proc = ctx.Process(
            target=serve_in_process,
            daemon=True,
            args=(
                src,
                frame_bytes,
                frames,
                rx.address,
                cport,
                ready,
                rate_mb_s,
                timeout_s,
            ),
        )
        proc.start()
        try:
            if not ready.wait(15):
                raise RuntimeError("fake DCA1000 process did not start")
            with Dca1000Control("127.0.0.1", cport, local=("127.0.0.1", 0), timeout_s=1.0) as ctl:
                ctl.setup()
                ctl.start_record()
                for f in rx.frames(idle_timeout_s=0.5, deadline_s=timeout_s):
                    now = time.perf_counter()
                    first = now if first is None else first
                    last = now
                    n += 1
                    k = f.index % 2
                    exact += bool(
                        f.complete
                        and f.data.tobytes() == src[k * frame_bytes : (k + 1) * frame_bytes]
                    )
                ctl.stop_record()
        finally:
            proc.join(5)
            if proc.is_alive():
                proc.terminate()
                proc.join(2)
    mb_s = (n - 1) * frame_bytes / (last - first) / 1e6 if n > 1 and last > first else 0.0
    st = asm.stats
    out = {
        "mb_per_s": round(mb_s, 1),
        "frames_sent": frames,
        "frames": n,
        "frames_exact": exact,
        "frames_flagged": st.frames_flagged,
        "packets": st.packets,
        "gaps": st.gaps,
    }
    if rate_mb_s is not None:
        out["pacing_mb_per_s"] = rate_mb_s
    return {f"{prefix}_{k}": v for k, v in out.items()}


def run(quick: bool = False) -> dict:
    """Flat dict of numbers: DSP ms per frame and loopback MB/s (quick: fewer frames)."""
    try:  # one core: also keep BLAS (the small per-point matrix products) single-threaded
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - comes with scikit-learn
        out = bench_dsp(10 if quick else 100)
    else:
        with threadpool_limits(limits=1):
            out = bench_dsp(10 if quick else 100)
    out.update(bench_loopback(8 if quick else 64))
    if not quick:
        out.update(bench_loopback(64, rate_mb_s=None, prefix="loopback_unpaced"))
    return out
