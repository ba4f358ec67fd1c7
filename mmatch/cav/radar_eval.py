"""Ego-motion evaluation over a folder of `mmatch-radar/1` files (the `mmatch egomotion` report).

The report is the JSON of DESIGN.md:
{"frames", "rejected", "velocity_error_mps": {"median", "p90"}, "moving_precision",
"moving_recall", "per_frame": [{"file", "velocity": [vx, vy], "moving": [indices]}]}.
Velocity errors are |v_est - v_gt| (m/s) over the frames that carry `gt_velocity` and got an
estimate; moving precision / recall pool the points of every frame carrying `gt_moving`
(a frame without an estimate calls no point moving, so its moving points count as missed).
Figures without ground truth are null; a frame without an estimate has velocity [null, null].
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mmatch.cav.config import EgoMotionConfig
from mmatch.cav.egomotion import fit_egomotion
from mmatch.errors import SceneFormatError
from mmatch.scene_io import load_radar_frame

log = logging.getLogger(__name__)


@dataclass
class RadarEvaluation:
    """The DESIGN.md report plus what the command line shows besides it."""

    report: dict
    rejected: list[SceneFormatError] = field(default_factory=list)
    no_estimate: list[tuple[str, str]] = field(default_factory=list)   # (file, reason)


def _stat(values: list[float]) -> dict:
    if not values:
        return {"median": None, "p90": None}
    a = np.asarray(values, np.float64)
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90))}


def evaluate_radar_files(paths: list[Path], config: EgoMotionConfig | None = None,
                         progress: Callable[[int, int], None] | None = None) -> RadarEvaluation:
    """Fit every file; rejected files are collected (with file and key), never fatal.

    progress: called with (files done, total) after each file.
    """
    cfg = config or EgoMotionConfig()
    per_frame, errors, rejected, no_estimate = [], [], [], []
    tp = fp = fn = 0
    has_moving_gt = False
    for k, path in enumerate(paths):
        if progress:
            progress(k, len(paths))
        try:
            rec = load_radar_frame(path)
        except SceneFormatError as exc:
            log.debug("rejected %s", exc)
            rejected.append(exc)
            continue
        e = fit_egomotion(rec["points"], cfg)
        if e.ok:
            velocity = [float(e.velocity[0]), float(e.velocity[1])]
            if rec["gt_velocity"] is not None:
                errors.append(float(np.linalg.norm(e.velocity - rec["gt_velocity"])))
        else:
            velocity = [None, None]
            no_estimate.append((Path(path).name, f"{e.status.value}: {e.reason}"))
        if rec["gt_moving"] is not None:
            has_moving_gt = True
            gt = np.asarray(rec["gt_moving"], bool)
            tp += int(np.sum(e.moving & gt))
            fp += int(np.sum(e.moving & ~gt))
            fn += int(np.sum(~e.moving & gt))
        per_frame.append({"file": Path(path).name, "velocity": velocity,
                          "moving": np.flatnonzero(e.moving).tolist()})
    if progress:
        progress(len(paths), len(paths))
    report = {
        "frames": len(per_frame),
        "rejected": len(rejected),
        "velocity_error_mps": _stat(errors),
        "moving_precision": (tp / (tp + fp) if tp + fp else 0.0) if has_moving_gt else None,
        "moving_recall": (tp / (tp + fn) if tp + fn else 1.0) if has_moving_gt else None,
        "per_frame": per_frame,
    }
    return RadarEvaluation(report=report, rejected=rejected, no_estimate=no_estimate)
