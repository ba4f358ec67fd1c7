"""`mmatch replay LOG`: a field log or a raw UART capture through the same per-frame path."""

from __future__ import annotations

import argparse

HELP = "replay an MCAP log (or a raw UART capture) through the vehicle loop; compare with the live run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="MCAP file, folder of MCAP files, or raw UART capture (.bin/.dat)")
    p.add_argument("--config", "-c", help="vehicle config (default: the one stored in the log)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one config value (repeatable)")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--fast", action="store_true", help="as fast as possible (default: recorded pace)")
    pace.add_argument("--speed", type=float, default=1.0, help="pace multiplier (default 1)")
    p.add_argument("--no-process", action="store_true", help="only decode (frames out), no pipeline")
    p.add_argument("--publish", action="store_true", help="publish results on Zenoh as live")
    p.add_argument("--log-dir", help="log the replay itself to this folder")
    p.add_argument("--fused-out", help="write the replayed fused results here (JSON lines)")
    p.add_argument("--frames-out", help="write the replayed radar frames here (JSON)")
    p.add_argument("--compare", action="store_true",
                   help="compare with the fused results recorded in the log; exit 1 on any difference, a result "
                        "missing or extra, or a log without recorded results")
    p.add_argument("--compare-eval", metavar="FILE",
                   help="compare with `mmatch eval --sequences --json FILE` (or its FILE.frames.json) on the scene "
                        "files the log was recorded from, frame by frame and exactly; exit 1 on any difference")
    p.add_argument("--json", help="write a summary JSON here")


def run(args: argparse.Namespace) -> int:
    import json

    from mmatch.edge.replay import replay
    from mmatch.errors import ConfigError

    if args.speed <= 0:
        raise ConfigError("--speed: must be > 0")
    summary = replay(args.log, config_path=args.config, sets=args.set, fast=args.fast,
                     speed=args.speed, process=not args.no_process, publish=args.publish,
                     log_dir=args.log_dir, fused_out=args.fused_out, frames_out=args.frames_out,
                     compare=args.compare, compare_eval_path=args.compare_eval)
    text = json.dumps(summary, indent=2)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    print(text)
    for key in ("compare", "compare_eval"):
        cmp = summary.get(key)
        if cmp is not None and not cmp["match"]:  # any difference, or nothing to compare
            return 1
    return 0
