"""`mmatch eval`: run the whole per-frame path on a folder of scene files and report accuracy."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mmatch.edge.commands.args import positive_int, unit_interval

HELP = "evaluate matching and alignment on a folder of mmatch-scene/1 files (table + DESIGN.md JSON)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mmatch.ego.registry import ALIGNERS, DEFAULT_ALIGNER, DEFAULT_MATCHER, MATCHERS
    p.add_argument("folder", help="folder of *.npz scene files")
    p.add_argument("--json", help="write the report here")
    p.add_argument("--matcher", default=DEFAULT_MATCHER, choices=sorted(MATCHERS),
                   help="which vehicles both views share")
    p.add_argument("--aligner", default=DEFAULT_ALIGNER, choices=sorted(ALIGNERS),
                   help="the transform between the two radars")
    p.add_argument("--jobs", type=positive_int, default=1, help="worker processes")
    add_scene_options(p)
    p.add_argument("--sequences", action="store_true",
                   help="the files are sequences (meta.sequence / meta.frame): run each through one tracking "
                        "fuser in frame order, as the vehicle service does, beside the per-frame mode "
                        "(JSON: docs/formats.md)")
    p.add_argument("--track-max-age", type=_nonneg, default=0.5, metavar="S",
                   help="with --sequences: the tracking fuser's track age limit, s (the service's "
                        "ego.track_max_age_s)")


def add_scene_options(p: argparse.ArgumentParser) -> None:
    """The options of how scene files are run that `mmatch eval` and `mmatch report` share:
    --cav, --descriptor-scale, --depth-scale, --doppler-sign, --confidence-threshold,
    --no-heading-prior."""
    p.add_argument("--cav", default="pipeline", choices=["pipeline", "labels"],
                   help="pipeline: CAV-side processing; labels: perfect separation from the files' labels")
    p.add_argument("--descriptor-scale", type=_scale, default=1.0, metavar="auto|FACTOR",
                   help="factor on appearance-descriptor distances; auto: measured on the folder "
                        "without labels; 1: as the files have them")
    p.add_argument("--depth-scale", type=_depth_scale, default=None, metavar="auto|FACTOR|EGO,CAV",
                   help="factor on each camera's box depths; auto (default): each camera calibrated to its "
                        "radar on the folder without labels, depths along the optical axis recognised and "
                        "turned into distances (1 within the spread of calibrated cameras; "
                        "with --sequences over each sequence's frames so far, as the vehicle service "
                        "does); one factor for both cameras, or the Ego's and the CAV's")
    p.add_argument("--doppler-sign", type=_doppler_sign, default=None, metavar="auto|1|-1",
                   help="how the files' Doppler counts: 1 as DESIGN.md (positive = range increasing), -1 "
                        "the other way round; auto (default): judged on the folder from which sign its "
                        "radars' ego-motion fits explain")
    p.add_argument("--confidence-threshold", type=unit_interval, default=None, metavar="P",
                   help="estimates less sure than P (0-1) are 'no estimate'; default: the fitted model's "
                        "threshold; 0 emits every estimate")
    p.add_argument("--no-heading-prior", dest="heading_prior", action="store_false",
                   help="run the Ego side as if neither radar's velocity gave the road direction "
                        "(a vehicle standing still or turning)")


def _nonneg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not 0.0 <= v < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def _scale(text: str) -> float | None:
    if text == "auto":
        return None
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto or a positive number, got {text!r}") from None
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"expected auto or a positive number, got {text!r}")
    return v


def _doppler_sign(text: str) -> int | None:
    if text == "auto":
        return None
    if text not in ("1", "-1", "+1"):
        raise argparse.ArgumentTypeError(f"expected auto, 1 or -1, got {text!r}")
    return int(text)


def _depth_scale(text: str) -> tuple[float, float] | None:
    if text == "auto":
        return None
    parts = text.split(",")
    try:
        values = [float(x) for x in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or not all(0 < v < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected auto, a positive factor or two (EGO,CAV), got {text!r}")
    return (values[0], values[-1])


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.commands.progress import Progress
    from mmatch.ego.align.baselines import missing_extra
    from mmatch.errors import ConfigError, ParseError
    from mmatch.evaluate import EvalConfig, evaluate_dir, format_table

    if not Path(args.folder).is_dir():
        raise ParseError(f"{args.folder} is not a folder")
    if not any(Path(args.folder).glob("*.npz")):
        raise ParseError(f"{args.folder}: no *.npz scene files (make some with `mmatch sim --out DIR`)")
    why = missing_extra(args.aligner)
    if why:
        raise ConfigError(why)
    cfg = EvalConfig(matcher=args.matcher, aligner=args.aligner, cav=args.cav,
                     descriptor_scale=args.descriptor_scale, confidence_threshold=args.confidence_threshold,
                     heading_prior=args.heading_prior, depth_scale=args.depth_scale,
                     doppler_sign=args.doppler_sign)
    if args.sequences:
        return _run_sequences(args, cfg)
    rep, results = evaluate_dir(args.folder, cfg, args.jobs, Progress("eval"))
    for r in results:
        if "rejected" in r:
            print(f"rejected: {r['rejected']}", file=sys.stderr)
    if rep["scenes"] == 0:
        raise ParseError(f"{args.folder}: every scene file ({rep['rejected']}) was rejected")
    print(format_table(rep))
    if args.json:
        _write(args.json, rep, ".scenes.json", results)
    return 0


def _write(path: str, rep: dict, suffix: str, rows) -> None:
    """The report as JSON at `path` and the per-scene rows beside it (`path` with `suffix`)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rep, indent=2))
    out.with_suffix(suffix).write_text(json.dumps(rows, indent=1))
    print(f"wrote {out}")


def _run_sequences(args: argparse.Namespace, cfg) -> int:
    from mmatch.edge.commands.progress import Progress
    from mmatch.errors import ParseError
    from mmatch.sequence_eval import SequenceEvalConfig, evaluate_sequences_dir, format_sequence_table

    if args.descriptor_scale is None:
        raise ParseError("--descriptor-scale auto: not with --sequences (the service has no folder to measure)")
    scfg = SequenceEvalConfig(eval=cfg, track_max_age_s=args.track_max_age)
    rep, results = evaluate_sequences_dir(args.folder, scfg, args.jobs, Progress("eval"))
    rejected = {r["file"]: r["rejected"] for rows in results.values() for r in rows if "rejected" in r}
    for text in rejected.values():
        print(f"rejected: {text}", file=sys.stderr)
    if rep["frames"] == 0:
        raise ParseError(f"{args.folder}: no frame of a sequence could be evaluated ({rep['rejected']} rejected)")
    print(format_sequence_table(rep))
    if args.json:
        _write(args.json, rep, ".frames.json", results)
    return 0
