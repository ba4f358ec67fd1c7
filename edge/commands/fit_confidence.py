"""`mmatch fit-confidence`: fit the probability model behind every estimate's confidence."""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from mmatch.edge.commands.args import positive_int

HELP = "fit the confidence model (P(within 2 m / 5 deg)) on folders of scene files, seeds apart from reporting"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="*", help="folders of *.npz scene files (with ground truth) to fit on")
    p.add_argument("--out", default=None,
                   help="model file to write (default: the packaged mmatch/ego/confidence_model.json)")
    p.add_argument("--max-gross", type=float, default=0.015,
                   help="gross-error rate among the emitted estimates the threshold must keep")
    p.add_argument("--min-coverage", type=float, default=0.8, help="share of scenes to keep when possible")
    p.add_argument("--matchers", default="consensus,rmnet",
                   help="comma-separated matchers whose candidates the model learns from (one model serves all)")
    p.add_argument("--jobs", type=positive_int, default=1, help="worker processes")
    p.add_argument("--no-without-heading", dest="without_heading", action="store_false",
                   help="skip the second model, for frame pairs without a heading prior (a radar standing "
                        "still or turning), fit on the same folders run without it")
    p.add_argument("--without-heading-folders", default=None, metavar="FOLDER[,FOLDER...]",
                   help="fit the second model on these folders instead (default: the same folders); e.g. "
                        "without oblique junctions, which without the velocities' prior no evidence tells "
                        "from a crossing at right angles (the road axes hold modulo 90 deg)")
    p.add_argument("--no-trees", dest="trees", action="store_false",
                   help="no boosted trees beside the regression (the confidence is the regression's probability)")
    p.add_argument("--trees-only", action="store_true",
                   help="keep the model file's regressions, thresholds and inflations; refit only the boosted "
                        "trees and choosers (on the default matcher's candidates)")
    p.add_argument("--threshold-on", action="append", default=[], metavar="FOLDER[,FOLDER...]",
                   help="a family of tuning folders (repeat for each family, e.g. wide and a harsher physics): "
                        "the threshold becomes the lowest (a multiple of 0.01) at which the gross rate among the "
                        "estimates a single frame emits, with the Fuser's other gates, stays within "
                        "--threshold-max-gross in every family (the default matcher, heading prior on; the model "
                        "for frame pairs without one keeps its threshold)")
    p.add_argument("--threshold-max-gross", type=float, default=0.01,
                   help="the gross rate among the emitted each --threshold-on family must keep")
    p.add_argument("--threshold-only", action="store_true",
                   help="keep the model file as it is and choose only its threshold (needs --threshold-on)")
    p.add_argument("--calibration-only", action="store_true",
                   help="keep the model file as it is and refit only the map from its probability to the "
                        "published confidence (the default matcher's chosen estimates on the folders; the "
                        "second model's on its folders, --without-heading-folders, run without the heading "
                        "prior, unless --no-without-heading)")
    p.add_argument("--inflation-only", action="store_true",
                   help="keep the model file as it is and refit only its covariance inflations on the folders "
                        "(the default matcher's published estimates; the second model's on its folders, "
                        "--without-heading-folders, run without the heading prior, unless --no-without-heading)")


def run(args: argparse.Namespace) -> int:
    from mmatch.ego.confidence import MODEL_PATH, load_model
    from mmatch.ego.confidence_fit import fit_model, neutral_model
    from mmatch.ego.registry import DEFAULT_MATCHER
    from mmatch.errors import ConfigError, ParseError

    from mmatch.ego.registry import MATCHERS

    matchers = [m for m in args.matchers.split(",") if m]
    for m in matchers:
        if m not in MATCHERS:
            raise ParseError(f"--matchers: unknown matcher {m!r}; choose from {', '.join(sorted(MATCHERS))}")
    families = [[f for f in fam.split(",") if f] for fam in args.threshold_on]
    for folder in [*args.folders, *(f for fam in families for f in fam), *_folders(args, False)]:
        if not Path(folder).is_dir() or not any(Path(folder).glob("*.npz")):
            raise ParseError(f"{folder}: not a folder of *.npz scene files")
    if args.trees_only and not args.trees:
        raise ParseError("--trees-only and --no-trees contradict each other")
    if args.threshold_only and not families:
        raise ParseError("--threshold-only needs at least one --threshold-on family")
    if not args.folders and not args.threshold_only:
        raise ParseError("give the folders to fit on (or --threshold-only)")
    only = (args.trees_only, args.threshold_only, args.inflation_only, args.calibration_only)
    if sum(only) > 1:
        raise ParseError("--trees-only, --threshold-only, --inflation-only and --calibration-only: one at a time")
    if args.calibration_only and not args.folders:
        raise ParseError("--calibration-only: give the folders to fit on")
    if not 0.0 <= args.threshold_max_gross < 1.0:
        raise ParseError(f"--threshold-max-gross: {args.threshold_max_gross} is not in [0, 1)")
    out = Path(args.out) if args.out else MODEL_PATH
    if any(only):
        what = ("--trees-only", "--threshold-only", "--inflation-only", "--calibration-only")[only.index(True)]
        kept = load_model(str(out)) if args.out else load_model()
        if kept is None:
            raise ParseError(f"{what}: no model at {out} to keep")
        model = _with_trees(kept, None, args) if args.trees_only else kept
        if args.inflation_only:
            model = _with_inflation(model, args)
        if families:
            model = _with_threshold(model, families, args)
        if args.calibration_only:
            model = _with_calibration(model, args)
        out.write_text(model.to_json() + "\n")
        _report(model)
        print(f"wrote {out}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        # the evaluation runs under a neutral model whatever is installed: the installed one would
        # choose each frame pair's candidate (its chooser) and so which one the polish refines,
        # and the data would follow it. From a neutral start the fit is reproducible: today's code
        # refits the packaged model from its folders byte for byte, while the same fit run under
        # the packaged model landed far from it (gross at coverage 0.8 21 against 12 of 1120 on
        # the wide tuning seeds; docs/history.md, 2026-12-07, late evening)
        try:
            load_model()
        except ConfigError as exc:              # stale features (evidence added or renamed)
            print(f"fit-confidence: {exc}; evaluating without it", file=sys.stderr)
        model_path = str(Path(tmp) / "neutral.json")     # no inflation: fit_model's default 1
        Path(model_path).write_text(neutral_model().to_json())
        priors = [True, False] if args.without_heading else [True]
        results = {heading: _evaluate(_folders(args, heading), matchers, model_path, heading, "fit", args.jobs)
                   for heading in priors}
    meta = {"folders": args.folders, "matchers": matchers}
    try:
        model = fit_model(results[True], args.max_gross, args.min_coverage, meta=meta)
        if args.without_heading:
            sub = fit_model(results[False], args.max_gross, args.min_coverage,
                            meta=dict(meta, folders=_folders(args, False), heading_prior=False))
            model = replace(model, without_heading=sub)
        if args.trees:
            reuse = results[True] if matchers == [DEFAULT_MATCHER] else None
            model = _with_trees(model, reuse, args)
    except ValueError as exc:
        raise ParseError(str(exc)) from exc
    if families:
        model = _with_threshold(model, families, args)
    model = _with_calibration(model, args)
    out.write_text(model.to_json() + "\n")
    _report(model)
    print(f"wrote {out}")
    return 0


def _with_trees(model, reuse: list[dict] | None, args: argparse.Namespace):
    """`model` with boosted trees fit on the folders' candidates of the default matcher, run
    under `model` itself: beside its first regression (heading prior known; `reuse`: those
    runs' results when already at hand) and, unless --no-without-heading, beside its second
    (the same folders run without the heading prior)."""
    from mmatch.ego.confidence_fit import fit_tree_stage
    from mmatch.ego.registry import DEFAULT_MATCHER
    from mmatch.errors import ParseError

    meta = {"folders": args.folders, "matcher": DEFAULT_MATCHER}
    try:
        first = reuse if reuse is not None else _runs(model, args.folders, True, "fit trees", args.jobs)
        out = fit_tree_stage(first, model, meta)
        if args.without_heading and model.without_heading is not None:
            second = _runs(model, _folders(args, False), False, "fit trees", args.jobs)
            sub = fit_tree_stage(second, model.without_heading,
                                 dict(meta, folders=_folders(args, False), heading_prior=False))
            out = replace(out, without_heading=sub)
    except ValueError as exc:
        raise ParseError(str(exc)) from exc
    return out


def _with_threshold(model, families: list[list[str]], args: argparse.Namespace):
    """`model` with the threshold `gated_threshold` chooses on the tuning families, each run
    under `model` by the default matcher with every candidate emitted."""
    from mmatch.ego.confidence_fit import gated_threshold

    runs = [_runs(model, fam, True, "threshold", args.jobs) for fam in families]
    thr, per = gated_threshold(runs, args.threshold_max_gross)
    for fam, res in zip(families, per):
        print(f"threshold {thr:.2f} on {','.join(fam)}: emitted {res['emitted']:.3f}, success {res['success']:.3f}, "
              f"gross among emitted {res['gross']:.4f}")
    choice = (f"{thr:.2f}: the lowest (a multiple of 0.01) at which gross among the emitted stays within "
              f"{args.threshold_max_gross} on each of " + "; ".join(",".join(f) for f in families))
    return replace(model, threshold=thr, meta=dict(model.meta, threshold_choice=choice))


def _with_inflation(model, args: argparse.Namespace):
    """`model` with its covariance inflations refit on the folders: each the factor that makes the
    95 % ellipse of the published estimates (the default matcher's, run under `model`, whose
    covariances carry its inflation) hold the truth for 95 % of the successful ones; the second
    model's on the folders run without the heading prior (unless --no-without-heading)."""
    from mmatch.ego.confidence_fit import fit_inflation

    def refit(sub, heading: bool):
        folders = _folders(args, heading)
        runs = _runs(model, folders, heading, "inflation", args.jobs)
        published = [dict(r["candidate"], covariance=r["covariance"]) for r in runs
                     if r.get("candidate") and r.get("covariance") is not None]
        factor = fit_inflation(published)
        inflation = sub.inflation * factor
        print(f"covariance inflation{'' if heading else ' without a heading prior'} {sub.inflation:.3f} -> "
              f"{inflation:.3f} (x {factor:.3f}) on {sum(p['success'] for p in published)} successful "
              f"estimates of {len(runs)} scenes")
        choice = f"{inflation:.3f}: refit alone (--inflation-only) on " + ",".join(folders)
        return replace(sub, inflation=inflation, meta=dict(sub.meta, inflation_choice=choice))

    out = refit(model, True)
    if args.without_heading and model.without_heading is not None:
        out = replace(out, without_heading=refit(model.without_heading, False))
    return out


def _with_calibration(model, args: argparse.Namespace):
    """`model` with each of its models' calibration (ProbabilityModel.calibration) fit on the
    folders: the default matcher's chosen estimate of every scene, run under `model` without a
    calibration and every candidate emitted (its raw probability, and whether it is right); the
    second model's on the folders run without the heading prior (unless --no-without-heading)."""
    import numpy as np

    from mmatch.ego.confidence_fit import fit_calibration
    from mmatch.errors import ParseError
    from mmatch.metrics import reliability

    sub0 = model.without_heading
    bare = replace(model, calibration=None,
                   without_heading=replace(sub0, calibration=None) if sub0 is not None else None)

    def refit(sub, heading: bool):
        folders = _folders(args, heading)
        runs = _runs(bare, folders, heading, "calibration", args.jobs)
        rows = [(r["confidence"], r["candidate"]["success"]) for r in runs
                if r.get("candidate") and r.get("confidence") is not None]
        p, y = np.array([c for c, _ in rows], float), np.array([s for _, s in rows], bool)
        try:
            cal = fit_calibration(p, y)
        except ValueError as exc:
            raise ParseError(f"calibration{'' if heading else ' without a heading prior'}: {exc}") from exc
        fitted = replace(sub, calibration=cal)
        before, after = reliability(p, y), reliability(fitted.published(p), y)
        print(f"calibration{'' if heading else ' without a heading prior'}: a {cal[0]:.3f}, b {cal[1]:.3f} on "
              f"{len(p)} chosen estimates ({y.mean():.3f} right, mean raw probability {p.mean():.3f}); expected "
              f"calibration error {before['ece']:.3f} -> {after['ece']:.3f}, Brier {before['brier']:.4f} -> "
              f"{after['brier']:.4f}; threshold {sub.threshold:.3f} publishes as {fitted.published(sub.threshold):.3f}")
        choice = f"a {cal[0]:.4f}, b {cal[1]:.4f}: fit on the chosen estimates of " + ",".join(folders)
        return replace(fitted, meta=dict(sub.meta, calibration_choice=choice))

    out = refit(model, True)
    if args.without_heading and sub0 is not None:
        out = replace(out, without_heading=refit(sub0, False))
    return out


def _folders(args: argparse.Namespace, heading: bool) -> list[str]:
    """The folders a model is fit on: the first model's (heading prior known), or the second's,
    for frame pairs without one (--without-heading-folders; by default the same)."""
    if heading or not args.without_heading_folders:
        return list(args.folders)
    return [f for f in args.without_heading_folders.split(",") if f]


def _runs(model, folders: list[str], heading: bool, label: str, jobs: int) -> list[dict]:
    """The default matcher's per-scene results on the folders under `model`, every candidate
    emitted, with or without the heading prior."""
    from mmatch.ego.registry import DEFAULT_MATCHER

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.json"
        path.write_text(model.to_json())
        return _evaluate(folders, [DEFAULT_MATCHER], str(path), heading, label, jobs)


def _evaluate(folders: list[str], matchers: list[str], model_path: str | None, heading: bool,
              label: str, jobs: int) -> list[dict]:
    """Per-scene results of every folder under each matcher (folder by folder), every candidate
    emitted, under the confidence model at model_path (None: the packaged one), with or
    without the heading prior."""
    from mmatch.edge.commands.progress import Progress
    from mmatch.evaluate import EvalConfig, evaluate_dir

    results: list[dict] = []
    for folder in folders:
        for m in matchers:
            cfg = EvalConfig(matcher=m, confidence_threshold=0.0, confidence_model=model_path, heading_prior=heading)
            progress = Progress(f"{label} {m}" + ("" if heading else " without heading"))
            _, res = evaluate_dir(folder, cfg, jobs, progress)
            results.extend(res)
    return results


def _report(model) -> None:
    for what, mdl in (("", model), (" without a heading prior", model.without_heading)):
        if mdl is None:
            continue
        m = mdl.meta
        print(f"fit{what} on {m['candidates']} candidate transforms of {m['scenes']} scenes "
              f"(success {m['candidate_success']:.3f}); chosen per scene: success {m['chosen_success']:.3f}, "
              f"gross {m['chosen_gross']:.3f}; threshold {mdl.threshold:.3f}, covariance inflation {mdl.inflation:.2f}")
        for name, c in sorted(zip(mdl.features, mdl.coef), key=lambda x: -abs(x[1])):
            print(f"  {name:<22} {c:+.3f}")
        if mdl.trees is not None and mdl.chooser is not None:
            t = mdl.meta["trees"]
            print(f"boosted trees{what}: {len(mdl.trees.feature)} of depth {mdl.trees.depth} and a chooser of "
                  f"{len(mdl.chooser.feature)} on {t['candidates']} candidates of {t['matcher']} "
                  f"(success {t['candidate_success']:.3f})")
