"""`mmatch ablation`: every matcher on the same scene files in one run (README table + JSON)."""

from __future__ import annotations

import argparse
from pathlib import Path

from mmatch.edge.commands.output import write_json

HELP = ("compare matchers (RM-net + verification, RM-net alone, consensus with RM-net pairs, consensus, "
        "descriptor, geometry) on one folder")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mmatch.ablation import ABLATION
    from mmatch.ego.registry import ALIGNERS, DEFAULT_ALIGNER, MATCHERS
    p.add_argument("folder", help="folder of *.npz scene files")
    p.add_argument("--matchers", default=None,
                   help=f"comma-separated, from {', '.join(sorted(MATCHERS))}; without it the ablation's "
                        f"{', '.join(ABLATION)}")
    p.add_argument("--aligner", default=DEFAULT_ALIGNER, choices=sorted(ALIGNERS), help="the same for every matcher")
    p.add_argument("--cav", default="pipeline", choices=["pipeline", "labels"],
                   help="pipeline: CAV-side processing; labels: perfect separation from the files' labels")
    p.add_argument("--jobs", type=int, default=1, help="worker processes")
    p.add_argument("--json", help="write {matcher: eval report} here")


def run(args: argparse.Namespace) -> int:
    from mmatch.ablation import markdown, run_ablation
    from mmatch.edge.commands.progress import Progress
    from mmatch.errors import ConfigError
    from mmatch.evaluate import EvalConfig

    from mmatch.ego.registry import MATCHERS

    if not Path(args.folder).is_dir():
        raise ConfigError(f"folder: {args.folder} is not a folder")
    from mmatch.ablation import ABLATION

    text = ",".join(ABLATION) if args.matchers is None else args.matchers
    matchers = tuple(m.strip() for m in text.split(",") if m.strip())
    unknown = [m for m in matchers if m not in MATCHERS]
    if unknown or not matchers:
        raise ConfigError(f"--matchers: unknown {unknown or 'empty list'}; choose from {', '.join(sorted(MATCHERS))}")
    reports = run_ablation(args.folder, matchers, EvalConfig(aligner=args.aligner, cav=args.cav),
                           args.jobs, lambda m: Progress(m))
    first = next(iter(reports.values()))
    print(f"{first['scenes']} scenes ({first['rejected']} rejected), aligner {args.aligner}, cav {args.cav}, "
          f"descriptor scale {first['config']['descriptor_scale']:.3f}")
    print(markdown(reports))
    if args.json:
        write_json(args.json, reports)
    return 0
