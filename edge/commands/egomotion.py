"""`mmatch egomotion DIR --json FILE`: Doppler ego-motion fit over `mmatch-radar/1` files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mmatch.edge.commands.output import write_json

HELP = "fit the radar's own velocity on every mmatch-radar/1 file of a folder and report errors"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR", help="folder of mmatch-radar/1 .npz files")
    p.add_argument("--json", metavar="FILE", help="write the DESIGN.md report here")
    p.add_argument("--threshold", type=float, metavar="MPS",
                   help="stationary threshold at boresight, m/s (default from the config)")


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3f}"


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from mmatch.edge.commands.progress import Progress
    from mmatch.cav.config import CavConfig
    from mmatch.cav.radar_eval import evaluate_radar_files

    from mmatch.errors import ParseError

    folder = Path(args.dir)
    if not folder.is_dir():
        raise ParseError(f"{folder}: not a folder")
    cfg = CavConfig().egomotion
    if args.threshold is not None:
        cfg = replace(cfg, threshold_mps=args.threshold)
        CavConfig(egomotion=cfg)                       # validates (ConfigError names the key)
    paths = sorted(folder.glob("*.npz"))
    if not paths:
        raise ParseError(f"{folder}: no *.npz radar frame files")
    result = evaluate_radar_files(paths, cfg, progress=Progress("egomotion"))
    for exc in result.rejected:
        print(f"rejected: {exc}", file=sys.stderr)
    for name, reason in result.no_estimate:
        print(f"no estimate: {name}: {reason}", file=sys.stderr)
    r = result.report
    if r["frames"] == 0:
        raise ParseError(f"{folder}: every radar frame file ({r['rejected']}) was rejected")
    err = r["velocity_error_mps"]
    print(f"frames {r['frames']}  rejected {r['rejected']}  no estimate {len(result.no_estimate)}")
    print(f"velocity error m/s: median {_fmt(err['median'])}  p90 {_fmt(err['p90'])}")
    print(f"moving points: precision {_fmt(r['moving_precision'])}  recall {_fmt(r['moving_recall'])}")
    if args.json:
        write_json(args.json, r, indent=1)
    return 0
