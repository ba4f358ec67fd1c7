"""`mmatch fit-separation`: fit the learned point-to-box membership of the CAV side."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "fit the learned point-to-box membership (CAV-side separation) on labelled scene folders"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="+", help="folders of *.npz scene files with point labels and box ids")
    p.add_argument("--out", default=None,
                   help="model file to write (default: the packaged mmatch/cav/membership_model.json)")
    p.add_argument("--seed", type=int, default=0, help="seed of the network's initialisation")
    p.add_argument("--threshold", type=float, default=0.5, help="probability above which a point joins a box")
    p.add_argument("--box-threshold", type=float, default=0.15,
                   help="probability of being a vehicle below which a box is not shared")
    p.add_argument("--no-context", dest="context", action="store_false",
                   help="skip the context stage (each point judged again against its box's core; in its "
                        "place the CAV side keeps each vehicle's main DBSCAN cluster)")
    p.add_argument("--box-only", action="store_true",
                   help="keep the membership stages of the model file --out names (default: the packaged "
                        "one) and refit only the false-detection model on them")


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from mmatch.cav.membership import (CONTEXT_FEATURES, FEATURES, MODEL_PATH, context_training_pairs,
                                       fit_membership, labelled_candidates, load_model, training_pairs)
    from mmatch.errors import ParseError
    from mmatch.scene_io import load_scene

    views = []
    for folder in args.folders:
        files = sorted(Path(folder).glob("*.npz"))
        if not files:
            raise ParseError(f"{folder}: no *.npz scene files")
        for f in files:
            s = load_scene(f)
            views += [s.ego, s.cav]
    prepared = labelled_candidates(views)         # each view's ego-motion and candidates, once
    out = Path(args.out) if args.out else MODEL_PATH
    if args.box_only:
        if not out.is_file():
            raise ParseError(f"--box-only: {out} holds no membership model to keep")
        model, Xb, _ = _with_box_model(load_model(str(out)), views, prepared, args.box_threshold)
        out.write_text(model.to_json() + "\n")
        print(f"refit the false-detection model on {len(Xb)} boxes, membership kept; wrote {out}")
        return 0
    X, y = training_pairs(views, prepared=prepared)
    try:
        model = fit_membership(X, y, seed=args.seed, threshold=args.threshold, meta={"folders": args.folders})
    except ValueError as exc:
        raise ParseError(str(exc)) from exc
    if args.context:
        X2, y2 = context_training_pairs(views, model, prepared=prepared)
        try:
            context = fit_membership(X2, y2, hidden=(64, 32), seed=args.seed, threshold=args.threshold,
                                     features=FEATURES + CONTEXT_FEATURES)
        except ValueError as exc:
            raise ParseError(str(exc)) from exc
        model = replace(model, context=context)
    model, Xb, yb = _with_box_model(model, views, prepared, args.box_threshold)
    out.write_text(model.to_json() + "\n")
    p = model.box.probability(Xb)
    drop = p < model.box.threshold
    stage2 = f", context stage {model.context.meta['validation_score']:.3f}" if model.context is not None else ""
    print(f"fit on {len(X)} candidate pairs of {len(views)} views ({y.mean():.3f} true); "
          f"validation accuracy {model.meta['validation_score']:.3f}{stage2}; boxes: {len(Xb)}, false ones not shared "
          f"{drop[~yb].mean():.2f}, real ones lost {drop[yb].mean():.3f} (on the training views); wrote {out}")
    return 0


def _with_box_model(model, views: list, prepared: list, threshold: float):
    """The model with its false-detection model fit on the views under its membership stages;
    and the boxes' features and truth."""
    from dataclasses import replace

    from mmatch.cav.membership import box_training_rows, fit_box_model
    from mmatch.errors import ParseError

    Xb, yb = box_training_rows(views, model, prepared=prepared)
    try:
        return replace(model, box=fit_box_model(Xb, yb, threshold)), Xb, yb
    except ValueError as exc:
        raise ParseError(str(exc)) from exc
