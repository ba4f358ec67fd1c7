"""`mmatch compare A.json B.json`: two evaluation runs of the same scenes, scene by scene."""

from __future__ import annotations

import argparse
from pathlib import Path

from mmatch.edge.commands.output import write_json

HELP = ("compare two `mmatch eval --json` runs of the same scenes scene by scene: outcome moves "
        "and an exact sign test for the scenes right and the gross estimates emitted")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("a", metavar="A.json", help="the first run's report (FILE.scenes.json or, with "
                                               "--sequences, FILE.frames.json beside it); several "
                                               "comma-separated are pooled")
    p.add_argument("b", metavar="B.json", help="the second run's report(s), likewise")
    p.add_argument("--json", metavar="FILE", help="write the comparison here")


def run(args: argparse.Namespace) -> int:
    from mmatch.compare import compare, format_comparison, load_rows

    a, b = args.a.split(","), args.b.split(",")
    result = compare(load_rows(a), load_rows(b))
    print(format_comparison(result, _name(a), _name(b)))
    if args.json:
        write_json(args.json, result)
    return 0


def _name(reports: list[str]) -> str:
    first = Path(reports[0]).stem
    return first if len(reports) == 1 else f"{first} +{len(reports) - 1}"
