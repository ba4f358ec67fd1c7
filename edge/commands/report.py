"""`mmatch report`: every method on the same scene files, tables and figures in one folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mmatch.edge.commands.args import positive_int
from mmatch.edge.commands.evaluate import add_scene_options

HELP = "compare MMatch, its ablation and point-cloud peers on a folder of scene files (tables, plots)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="folder of *.npz scene files")
    p.add_argument("--out", required=True, help="report folder (report.json, summary.md, config.json, figures)")
    from mmatch.report.methods import METHODS
    p.add_argument("--methods", default=None,
                   help="comma-separated method keys or MATCHER+ALIGNER specs; keys: "
                        + ", ".join(m.key for m in METHODS) + " (default: every registered one; a peer "
                        "whose library is missing is skipped with a message)")
    p.add_argument("--jobs", type=positive_int, default=2, help="worker processes")
    add_scene_options(p)
    p.add_argument("--no-plots", action="store_true", help="tables and JSON only (no matplotlib needed)")


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.commands.progress import Progress
    from mmatch.errors import ConfigError, ParseError
    from mmatch.report.methods import default_methods, resolve
    from mmatch.evaluate import EvalConfig
    from mmatch.report.run import evaluate_methods, write_report

    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise ConfigError(f"--out {args.out} is a file, not a folder")
    if not Path(args.folder).is_dir():
        raise ParseError(f"{args.folder} is not a folder")
    if not any(Path(args.folder).glob("*.npz")):
        raise ParseError(f"{args.folder}: no *.npz scene files (make some with `mmatch sim --out DIR`)")
    methods = resolve(args.methods.split(",")) if args.methods else default_methods()
    if not args.no_plots:
        from mmatch.report.plots import pyplot
        pyplot()                                    # fail now, not after the run, without matplotlib
    print(f"report: {len(methods)} methods on {args.folder} ({args.jobs} jobs)", flush=True)
    base = EvalConfig(cav=args.cav, descriptor_scale=args.descriptor_scale,
                      confidence_threshold=args.confidence_threshold, heading_prior=args.heading_prior,
                      depth_scale=args.depth_scale, doppler_sign=args.doppler_sign)
    run_ = evaluate_methods(args.folder, methods, base, args.jobs, Progress("report"))
    for m, why in run_.skipped:
        print(f"skipped {m.key}: {why}", file=sys.stderr)
    if not run_.runs:
        raise ParseError("no method could run here (see the skipped lines)")
    for r in run_.runs[0].results:
        if "rejected" in r:
            print(f"rejected: {r['rejected']}", file=sys.stderr)
    if run_.runs[0].eval["scenes"] == 0:
        raise ParseError(f"{args.folder}: every scene file ({len(run_.files)}) was rejected")
    options = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    rep = write_report(args.out, run_, args.jobs, not args.no_plots, options)
    for m in rep["methods"]:
        d = m["derived"]
        print(f"{m['label']:<34} success {d['success']['5deg_2m']:.3f} / {d['success']['2deg_1m']:.3f} / "
              f"{d['success']['1deg_0.5m']:.3f}  RTE median {m['eval']['rte_m']['median']:.2f} m  "
              f"{d['ms_per_frame']:.1f} ms/frame")
    print(f"wrote {Path(args.out) / 'summary.md'}, report.json, config.json"
          + (f" and {len(rep['figures'])} figure files" if rep["figures"] else ""))
    return 0
