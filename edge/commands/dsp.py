"""`mmatch dsp`: turn a DCA1000 raw ADC capture into radar points per frame."""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

HELP = "process a DCA1000 raw ADC capture (*_Raw_*.bin) with its .cfg into points per frame"

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cfg", help="the radar .cfg the capture was recorded with")
    p.add_argument(
        "--adc",
        nargs="+",
        help="raw capture file(s), in order (_Raw_0.bin _Raw_1.bin ...)",
    )
    p.add_argument(
        "--angle-study",
        action="store_true",
        help="instead: measure our DSP's angle errors on synthesised point targets and vehicles "
        "per SNR band, next to the simulator's model (mmatch/sim/radar_errors.py); --cfg "
        "optional (default: the AWR2243 bench cfg)",
    )
    p.add_argument(
        "--frames", type=int, default=120, help="--angle-study: frames per kind (default 120)"
    )
    p.add_argument("--seed", type=int, default=0, help="--angle-study: seed (default 0)")
    p.add_argument("--json", help="write {frames, points_per_frame, points} here")
    p.add_argument(
        "--lanes",
        choices=("4", "2"),
        default="4",
        help="LVDS layout: 4 = interleaved AR1243/AWR2243, 2 = xWR16xx/18xx/68xx",
    )
    p.add_argument(
        "--antenna",
        default="awr2243boost",
        choices=("awr2243boost", "awr1843boost", "xwr16xxboost"),
        help="antenna layout (drivers/dca1000/antenna.py)",
    )
    p.add_argument("--mirror-x", action="store_true", help="mirror the antenna layout in x")
    p.add_argument("--iq-swap", action="store_true", help="Q comes before I in each sample pair")
    p.add_argument("--cfar", choices=("ca", "os"), default="ca", help="CFAR noise estimator")
    p.add_argument(
        "--average",
        choices=("ca", "cago", "caso"),
        help="override the cfg's CA averaging in range (cfarCfg averageMode 0/1/2)",
    )
    p.add_argument("--threshold-db", type=float, help="override the cfg's CFAR threshold (dB)")
    p.add_argument(
        "--clutter-removal", choices=("on", "off"), help="override the cfg's clutterRemoval"
    )
    p.add_argument("--max-frames", type=int, help="process at most this many frames")


def run(args: argparse.Namespace) -> int:
    if args.angle_study:
        return _angle_study(args)
    if not args.cfg or not args.adc:
        args._parser.error("--cfg and --adc are required (or --angle-study)")
    import numpy as np

    from mmatch.drivers.dca1000.antenna import LAYOUTS
    from mmatch.drivers.dca1000.dsp import make_dsp
    from mmatch.drivers.dca1000.layout import raw_to_cube
    from mmatch.drivers.dca1000.rawfile import RawCapture
    from mmatch.drivers.ti.cfg import load_cfg
    from mmatch.errors import ConfigError

    cfg = load_cfg(args.cfg)
    if args.antenna.lower() not in LAYOUTS:
        raise ConfigError(
            f"unknown antenna layout {args.antenna!r}; known: {', '.join(sorted(LAYOUTS))}"
        )
    antenna = LAYOUTS[args.antenna.lower()]
    if args.mirror_x:
        antenna = antenna.mirror_x()
    overrides: dict = {"cfar": args.cfar}
    if args.threshold_db is not None:
        overrides["threshold_db"] = args.threshold_db
    if args.average is not None:
        overrides["average"] = args.average
    if args.clutter_removal is not None:
        overrides["clutter_removal"] = args.clutter_removal == "on"
    geom, dsp = make_dsp(
        cfg, "4lane" if args.lanes == "4" else "2lane", antenna, args.iq_swap, **overrides
    )
    expected = _num_frames(cfg)
    capture = RawCapture(args.adc, geom, expected_frames=expected)
    n = len(capture) if args.max_frames is None else min(len(capture), args.max_frames)
    points = []
    t0 = time.perf_counter()
    for k in range(n):
        pts = dsp.process(raw_to_cube(capture.frame(k), geom)).points
        points.append(np.round(pts.astype(np.float64), 4).tolist())
    dt = time.perf_counter() - t0
    counts = [len(p) for p in points]
    log.info(
        "%d frames in %.2f s (%.1f ms/frame), %d points", n, dt, 1e3 * dt / max(n, 1), sum(counts)
    )
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"frames": n, "points_per_frame": counts, "points": points}))
    median = int(np.median(counts)) if counts else 0
    print(
        f"{n} frames, {sum(counts)} points (median {median} per frame)"
        + (f" -> {args.json}" if args.json else "")
    )
    return 0


def _num_frames(cfg) -> int | None:
    """frameCfg numFrames (None when 0 = infinite or absent)."""
    for _, cmd, a in cfg.commands:
        if cmd == "frameCfg":
            n = int(float(a[3]))
            return n if n > 0 else None
    return None


def _angle_study(args: argparse.Namespace) -> int:
    from mmatch.drivers.dca1000.angle_study import (
        BANDS,
        THRESHOLD_DB,
        TOP_BAND,
        azimuth_table,
        band_table,
        format_rows,
        run_study,
    )
    from mmatch.drivers.ti.cfg import load_cfg
    from mmatch.errors import ConfigError

    if args.frames < 1:
        raise ConfigError(f"--frames must be >= 1, got {args.frames}")
    cfg = load_cfg(args.cfg) if args.cfg else None
    t0 = time.perf_counter()
    for kind, extended in (("vehicles (2-5 scatterers per cell)", True), ("point targets", False)):
        sample = run_study(extended, args.frames, args.seed, cfg)
        rows = band_table(sample, bands=(*BANDS, TOP_BAND))
        print(
            format_rows(
                f"{kind}: {len(sample.snr_db)} of {sample.placed} matched; |error| deg, "
                "DSP vs model, per band of reported SNR (the >45 row is not held, see "
                "angle_study.TOP_BAND)",
                "SNR dB",
                rows,
            )
        )
        print(format_rows(f"{kind}, 15-30 dB, per |azimuth|", "|az| deg", azimuth_table(sample)))
        print()
    print(
        f"CFAR threshold {THRESHOLD_DB:g} dB, {args.frames} frames per kind, seed {args.seed}, "
        f"{time.perf_counter() - t0:.1f} s"
    )
    return 0
