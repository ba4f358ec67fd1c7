"""`mmatch transfer`: the scenes of a folder again under other cameras, detectors and radars."""

from __future__ import annotations

import argparse
from pathlib import Path

from mmatch.edge.commands.args import positive_int
from mmatch.edge.commands.output import write_json

HELP = ("evaluate a folder as it is and with one convention or constant changed at a time "
        "(camera resolution, point and detection order, detector scores, depth bias, SNR, "
        "elevation, returns): what our figures hinge on")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mmatch.transfer import CHECKS

    p.add_argument("folder", help="folder of *.npz scene files (with labels: each check also runs on "
                                  "perfect separation)")
    p.add_argument("--checks", default=None,
                   help=f"comma-separated, from {', '.join(CHECKS)} (default: all)")
    p.add_argument("--scenes", type=positive_int, default=None, help="the first N scene files only")
    p.add_argument("--jobs", type=positive_int, default=1, help="worker processes")
    p.add_argument("--json", help="write the figures here")


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.commands.progress import Progress
    from mmatch.errors import ConfigError
    from mmatch.transfer import markdown, parse_checks, run_transfer

    if not Path(args.folder).is_dir():
        raise ConfigError(f"folder: {args.folder} is not a folder")
    result = run_transfer(args.folder, parse_checks(args.checks), jobs=args.jobs, max_scenes=args.scenes,
                          progress=Progress("transfer"))
    ref = result["checks"]["none"]
    print(f"{result['scenes']} scene files, {ref['pipeline']['rejected']} rejected "
          f"({ref['labels']['rejected']} for perfect separation, which needs labels); invariances must "
          f"change no scene, shifts show what they cost")
    print(markdown(result))
    if args.json:
        write_json(args.json, result)
    broken = [n for n, e in result["checks"].items() if e["kind"] == "invariance"
              and (e["pipeline"]["changed_scenes"] or e["labels"]["changed_scenes"])]
    return 1 if broken else 0
