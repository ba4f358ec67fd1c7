"""Transfer checks (`mmatch transfer`): the same scenes with one convention or constant changed.

Our figures come from one simulator. Scene files from other code follow the same format but not
necessarily our camera, detector or radar: another resolution, another score calibration, a
biased monocular depth, fewer returns. Each check rewrites both views of every scene one way
and evaluates them again, with the pipeline and with perfect separation (`--cav labels`):

- invariances, whose results must not change at all: a camera of twice the resolution (K and
  boxes x 2), the radar points in another order (TI lists them by range; other code however it
  likes), the detections in another order (a detector lists them by score). A changed scene
  is a bug: the first of these found RM-net reading box heights as if every camera had a
  1000 px focal length.
- shifts beyond the physics family, whose cost is measured: detection scores x 0.6, monocular
  depth x 0.85 and x 1.15, SNR +10 dB and -6 dB, no elevation (z = 0), half the returns, half
  or twice the stationary world's returns, appearance descriptors that say less (half of each
  histogram replaced by a random one) or one camera's hues off the other's by a histogram bin.

Each check is seeded per scene from the file name, so a run is repeatable.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mmatch.cav.depth_scale import box_bearings
from mmatch.cav.doppler_sign import judge_sign, sign_vote, with_sign
from mmatch.cav.egomotion import fit_egomotion
from mmatch.errors import ConfigError, MMatchError
from mmatch.evaluate import EvalConfig, depth_calibrations, evaluate_with, report, scene_depth_evidence
from mmatch.scene_io import load_scene
from mmatch.types import DESCRIPTOR_GROUPS, Scene, View


def _resolution(factor: float) -> Callable[[View, np.random.Generator], View]:
    def apply(view: View, rng: np.random.Generator) -> View:
        K = np.array(view.camera.K, np.float64)
        K[:2] *= factor
        w, h = view.camera.image_size
        boxes = np.array(view.boxes, np.float32)
        boxes[:, :4] *= factor
        size = (int(round(w * factor)), int(round(h * factor)))
        camera = replace(view.camera, K=K, image_size=size)
        return replace(view, boxes=boxes, camera=camera)
    return apply


def _keep_points(view: View, rows: np.ndarray) -> View:
    labels = None if view.point_labels is None else view.point_labels[rows]
    return replace(view, points=view.points[rows], point_labels=labels)


def _shuffled(view: View, rng: np.random.Generator) -> View:
    return _keep_points(view, rng.permutation(len(view.points)))


def _half_points(view: View, rng: np.random.Generator) -> View:
    return _keep_points(view, np.flatnonzero(rng.random(len(view.points)) < 0.5))


def _azimuth_noise(sigma_deg: float) -> Callable[[View, np.random.Generator], View]:
    def apply(view: View, rng: np.random.Generator) -> View:
        points = np.array(view.points, np.float32)
        r = np.hypot(points[:, 0], points[:, 1])
        az = np.arctan2(points[:, 0], points[:, 1]) + np.radians(sigma_deg) * rng.standard_normal(len(points))
        points[:, 0], points[:, 1] = r * np.sin(az), r * np.cos(az)
        return replace(view, points=points)
    return apply


def _more_points(times: int) -> Callable[[View, np.random.Generator], View]:
    """Every return `times` times, each copy 0.1 m, 1 deg and 0.1 m/s apart (a denser radar)."""
    def apply(view: View, rng: np.random.Generator) -> View:
        p = np.array(view.points, np.float64)
        r, az = np.hypot(p[:, 0], p[:, 1]), np.arctan2(p[:, 0], p[:, 1])
        n = len(p)
        copies = [p]
        for _ in range(times - 1):
            r2 = r + 0.1 * rng.standard_normal(n)
            az2 = az + np.radians(1.0) * rng.standard_normal(n)
            copy = p.copy()
            copy[:, 0], copy[:, 1] = r2 * np.sin(az2), r2 * np.cos(az2)
            copy[:, 3] += 0.1 * rng.standard_normal(n)
            copies.append(copy)
        labels = None if view.point_labels is None else np.tile(view.point_labels, times)
        return replace(view, points=np.concatenate(copies).astype(np.float32), point_labels=labels)
    return apply


def _stationary(view: View) -> np.ndarray:
    """bool (N,) the view's returns from the stationary world: its labelled background (label -1)
    when the file has labels, else what its own ego-motion fit does not call moving (every
    return of a frame the fit finds no velocity in)."""
    if view.point_labels is not None:
        return np.asarray(view.point_labels) == -1
    return ~fit_egomotion(np.asarray(view.points, np.float32)).moving


def _background_kept(share: float) -> Callable[[View, np.random.Generator], View]:
    """Each of the stationary world's returns (`_stationary`) kept with probability `share`, the
    vehicles' as they are: surroundings or a CFAR setting that give fewer background returns.
    Our physics draws no such constant: a view's stationary returns vary with its surroundings
    only (37-189 a view, 5th to 95th percentile of wide hard seed 1)."""
    def apply(view: View, rng: np.random.Generator) -> View:
        still = _stationary(view)
        return _keep_points(view, np.flatnonzero(~still | (rng.random(len(still)) < share)))
    return apply


def _background_doubled(view: View, rng: np.random.Generator) -> View:
    """Each of the stationary world's returns (`_stationary`) once more, 5 cm away (denser
    surroundings), the vehicles' as they are."""
    still = _stationary(view)
    p = np.array(view.points, np.float32)
    extra = p[still].copy()
    extra[:, :2] += (0.05 * rng.standard_normal((len(extra), 2))).astype(np.float32)
    labels = None if view.point_labels is None else \
        np.concatenate([view.point_labels, view.point_labels[still]])
    return replace(view, points=np.concatenate([p, extra]), point_labels=labels)


HUE_BINS = DESCRIPTOR_GROUPS[0][1]     # the hue histogram: the first entries (DESIGN.md)


def _descriptor_noise(share: float) -> Callable[[View, np.random.Generator], View]:
    """Each H, S and V histogram of every descriptor mixed with a random one (flat Dirichlet
    draw) at `share`: a camera or a detector whose boxes say less about a vehicle's colour."""
    def apply(view: View, rng: np.random.Generator) -> View:
        f = np.array(view.features, np.float64)
        for lo, hi in DESCRIPTOR_GROUPS:
            mass = f[:, lo:hi].sum(axis=1, keepdims=True)
            f[:, lo:hi] = (1 - share) * f[:, lo:hi] + share * mass * rng.dirichlet(np.ones(hi - lo), len(f))
        return replace(view, features=f.astype(np.float32))
    return apply


def _no_colour(view: View, rng: np.random.Generator) -> View:
    """Every descriptor all zero: a sender that measures no colour (DESIGN.md's histogram unfilled)."""
    return replace(view, features=np.zeros_like(np.asarray(view.features, np.float32)))


def _hue_shift(bins: float) -> Callable[[View, np.random.Generator], View]:
    """The hue histogram turned by `bins` bins (a fraction spreads each bin over two): a camera
    whose colour response is off by bins x 180 / 16 OpenCV hue units."""
    k, w = int(np.floor(bins)), bins - np.floor(bins)

    def apply(view: View, rng: np.random.Generator) -> View:
        f = np.array(view.features, np.float32)
        h = f[:, :HUE_BINS].copy()
        f[:, :HUE_BINS] = (1 - w) * np.roll(h, k, axis=1) + w * np.roll(h, k + 1, axis=1)
        return replace(view, features=f)
    return apply


def _box_column(col: int, factor: float) -> Callable[[View, np.random.Generator], View]:
    def apply(view: View, rng: np.random.Generator) -> View:
        boxes = np.array(view.boxes, np.float32)
        boxes[:, col] *= factor
        return replace(view, boxes=boxes)
    return apply


def _depth_offset(offset_m: float) -> Callable[[View, np.random.Generator], View]:
    def apply(view: View, rng: np.random.Generator) -> View:
        boxes = np.array(view.boxes, np.float32)
        boxes[:, 5] = np.maximum(boxes[:, 5] + offset_m, 1.0)
        return replace(view, boxes=boxes)
    return apply


def _depth_along_axis(view: View, rng: np.random.Generator) -> View:
    """Depth along the camera's optical axis instead of the distance to the vehicle centre."""
    boxes = np.array(view.boxes, np.float32)
    bearing = box_bearings(boxes.astype(np.float64), np.asarray(view.camera.K, np.float64))
    boxes[:, 5] *= np.cos(bearing).astype(np.float32)
    return replace(view, boxes=boxes)


def _point_column(col: int, offset: float | None) -> Callable[[View, np.random.Generator], View]:
    def apply(view: View, rng: np.random.Generator) -> View:
        points = np.array(view.points, np.float32)
        points[:, col] = 0.0 if offset is None else points[:, col] + offset
        return replace(view, points=points)
    return apply


def _doppler_flipped(view: View, rng: np.random.Generator) -> View:
    """Doppler with the other sign convention (positive = range decreasing)."""
    return replace(view, points=with_sign(view.points, -1))


def _box_permutation(view: View, rng: np.random.Generator) -> np.ndarray:
    return rng.permutation(len(view.boxes))


def _reordered_boxes(view: View, perm: np.ndarray) -> View:
    """The view with its detections (boxes, descriptors, ids) listed as perm (new k = old perm[k])."""
    ids = None if view.box_ids is None else view.box_ids[perm]
    return replace(view, boxes=view.boxes[perm], features=view.features[perm], box_ids=ids)


@dataclass(frozen=True)
class Check:
    """One rewrite of a view: `kind` "invariance" (results must stay the same) or "shift".
    `apply` rewrites a view; `box_order`, when given instead, draws a new order of its
    detections (the true pairs and the reported ones are mapped through it)."""

    name: str
    kind: str
    description: str
    apply: Callable[[View, np.random.Generator], View] | None = None
    box_order: Callable[[View, np.random.Generator], np.ndarray] | None = None
    ego_only: bool = False          # `apply` rewrites the Ego's view only (one camera unlike the other)


CHECKS: dict[str, Check] = {c.name: c for c in (
    Check("resolution-2x", "invariance", "camera of twice the resolution (K, image and boxes x 2)",
          _resolution(2.0)),
    Check("point-order", "invariance", "radar points (and their labels) in a random order",
          _shuffled),
    Check("box-order", "invariance", "detections (boxes, descriptors, ids) in a random order",
          box_order=_box_permutation),
    Check("doppler-sign", "invariance", "Doppler with the other sign (positive = range decreasing), "
          "judged on the folder", _doppler_flipped),
    Check("scores-0.6", "shift", "detection scores x 0.6 (a detector calibrated lower)",
          _box_column(4, 0.6)),
    Check("depth-0.85", "shift", "monocular depth x 0.85 (a biased depth estimate)",
          _box_column(5, 0.85)),
    Check("depth-1.15", "shift", "monocular depth x 1.15", _box_column(5, 1.15)),
    Check("depth-near-face", "shift", "monocular depth - 2 m (to the nearest face, not the centre)",
          _depth_offset(-2.0)),
    Check("depth-z", "shift", "monocular depth along the optical axis, not to the vehicle centre",
          _depth_along_axis),
    Check("no-depth", "shift", "monocular depth 0 for every box (a detector without a depth output)",
          _box_column(5, 0.0)),
    Check("snr+10", "shift", "SNR + 10 dB (another radar's SNR scale)", _point_column(4, 10.0)),
    Check("snr-6", "shift", "SNR - 6 dB", _point_column(4, -6.0)),
    Check("no-elevation", "shift", "z = 0 for every return (a radar without elevation)",
          _point_column(2, None)),
    Check("half-points", "shift", "every radar return kept with probability 0.5", _half_points),
    Check("double-points", "shift", "every radar return twice, the copy 0.1 m, 1 deg, 0.1 m/s apart (a denser radar)",
          _more_points(2)),
    Check("8x-points", "shift", "every radar return 8 times, the copies as double-points' (a much denser radar)",
          _more_points(8)),
    Check("half-background", "shift", "each stationary-world return kept with probability 0.5 "
          "(sparser surroundings, another CFAR); the vehicles' as they are", _background_kept(0.5)),
    Check("double-background", "shift", "each stationary-world return twice, the copy 5 cm away "
          "(denser surroundings)", _background_doubled),
    Check("azimuth+1.5deg", "shift", "1.5 deg more azimuth noise on every return (an array beyond the family)",
          _azimuth_noise(1.5)),
    Check("descriptor-noise", "shift", "half of each descriptor histogram replaced by a random one (less appearance)",
          _descriptor_noise(0.5)),
    Check("no-colour", "shift", "every descriptor all zero (a sender without colour)", _no_colour),
    Check("hue+1bin", "shift", "the Ego camera's hues 11.25 OpenCV units off the CAV's (twice the family's spread)",
          _hue_shift(1.0), ego_only=True),
)}
NONE = "none"


def perturb(scene: Scene, check: Check) -> Scene:
    """Both views of `scene` rewritten by `check`, seeded from the scene's name (repeatable);
    the true pairs follow the detections when the check reorders them."""
    return _perturbed(scene, check)[0]


def _perturbed(scene: Scene, check: Check) -> tuple[Scene, tuple[np.ndarray, np.ndarray]]:
    """`perturb`, and each view's order of its detections (new k = original order[k])."""
    rng = np.random.default_rng(zlib.crc32(f"{scene.name}/{check.name}".encode()))
    if check.box_order is None:
        orders = (np.arange(len(scene.ego.boxes)), np.arange(len(scene.cav.boxes)))
        views = check.apply(scene.ego, rng), scene.cav if check.ego_only else check.apply(scene.cav, rng)
        return replace(scene, ego=views[0], cav=views[1]), orders
    orders = (check.box_order(scene.ego, rng), check.box_order(scene.cav, rng))
    new_of = [np.argsort(o) for o in orders]                       # original index -> new index
    pairs = np.asarray(scene.gt_pairs, np.int64).reshape(-1, 2)
    gt = np.column_stack([new_of[0][pairs[:, 0]], new_of[1][pairs[:, 1]]]).astype(np.int32)
    ego, cav = _reordered_boxes(scene.ego, orders[0]), _reordered_boxes(scene.cav, orders[1])
    return replace(scene, ego=ego, cav=cav, gt_pairs=gt), orders


def parse_checks(text: str | None) -> list[str]:
    """Check names from a comma-separated list (None: every check); unknown names raise ConfigError."""
    names = list(CHECKS) if text is None else [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in CHECKS]
    if unknown or not names:
        raise ConfigError(f"--checks: unknown {unknown or 'empty list'}; choose from {', '.join(CHECKS)}")
    return names


def _evaluate(task: tuple[str, str, EvalConfig]) -> dict:
    """One scene under one check: the per-scene result, or {"rejected": why} for a file that is
    no scene or (with perfect separation) has no labels."""
    path, name, cfg = task
    try:
        scene = load_scene(path)
        orders = None
        if name != NONE:
            scene, orders = _perturbed(scene, CHECKS[name])
        r, _ = evaluate_with(scene, cfg)
    except MMatchError as exc:                  # not a scene, or no labels for perfect separation
        return {"file": path, "rejected": str(exc)}
    out = {k: r[k] for k in ("status", "box_pairs", "T_ego_cav", "tp", "predicted", "gt_pairs", "rre_deg",
                             "rte_m", "success", "payload_bytes", "stages_ms", "confidence", "candidate")}
    if orders is not None:                          # the reported pairs in the file's box indices
        out["box_pairs"] = [[int(orders[0][a]), int(orders[1][b])] for a, b in out["box_pairs"]]
    out["box_pairs"] = sorted(out["box_pairs"])
    return out


def _calibration_evidence(task: tuple[str, str]) -> tuple[dict, tuple[float, float]]:
    """One scene's camera depth evidence under one check, by Doppler sign ({1: ..., -1: ...};
    None: no scene), and its two radars' votes on that sign (cav/doppler_sign.py; NaN: none)."""
    path, name = task
    try:
        scene = load_scene(path)
        if name != NONE:
            scene, _ = _perturbed(scene, CHECKS[name])
        return ({s: scene_depth_evidence(scene, s) for s in (1, -1)},
                (sign_vote(scene.ego.points), sign_vote(scene.cav.points)))
    except MMatchError:
        return {1: None, -1: None}, (float("nan"), float("nan"))


def _changed(a: list[dict], b: list[dict]) -> int:
    """How many scenes differ in status, pairs or transform (1 mm / 1e-6) between two runs
    (rejected in both: the same)."""
    def same(x: dict, y: dict) -> bool:
        if ("rejected" in x) or ("rejected" in y):
            return ("rejected" in x) == ("rejected" in y)
        if x["status"] != y["status"] or x["box_pairs"] != y["box_pairs"]:
            return False
        if (x["T_ego_cav"] is None) != (y["T_ego_cav"] is None):
            return False
        return x["T_ego_cav"] is None or np.allclose(x["T_ego_cav"], y["T_ego_cav"], atol=1e-3)
    return sum(not same(x, y) for x, y in zip(a, b))


def _summary(rep: dict) -> dict:
    """What a check did to the figures and to how sure the output says it is: pair F1, success,
    coverage (emitted at the default gate), gross_rate (among the emitted), gross_at_0.8 (the
    risk-coverage curve at coverage 0.8) and calibration_error (expected calibration error of
    the published confidences, evaluate.py `sureness_report`). A shift that leaves F1 alone may
    still make the confidence lie: the gross rate among the emitted and the calibration error
    say so."""
    p, r = rep["pair_precision"], rep["pair_recall"]
    at = {round(e["coverage"], 2): e for e in rep["risk_coverage"]}
    return {"scenes": rep["scenes"], "rejected": rep["rejected"],
            "pair_f1": 2 * p * r / (p + r) if p + r else 0.0, "success_rate": rep["success_rate"],
            "coverage": rep["coverage"], "gross_rate": rep["gross_rate"],
            "gross_at_0.8": at.get(0.8, {}).get("gross_rate"),
            "calibration_error": rep["reliability"]["ece"]}


def run_transfer(folder: str | Path, checks: list[str], cfg: EvalConfig = EvalConfig(), jobs: int = 1,
                 max_scenes: int | None = None, progress: Callable[[int, int], None] | None = None) -> dict:
    """Evaluate the folder's scenes as they are and under each check, with the pipeline and with
    perfect separation: {"scenes": n, "checks": {name: {"kind", "description", cav: summary
    (+ "changed_scenes": scenes whose status, pairs or transform differ from the unchanged run)}}}."""
    files = sorted(str(p) for p in Path(folder).glob("*.npz"))[:max_scenes]
    if not files:
        raise ConfigError(f"folder: no *.npz scene files in {folder}")
    names = [NONE] + [n for n in checks if n != NONE]
    results: list[dict] = []
    with ProcessPoolExecutor(max_workers=jobs) if jobs > 1 else _Serial() as pool:
        cfgs = {n: cfg for n in names}
        if cfg.depth_scale is None or cfg.doppler_sign is None:
            # each check's cameras calibrated, and its Doppler sign judged, on its own scenes
            found = list(pool.map(_calibration_evidence, [(f, n) for n in names for f in files], chunksize=4))
            for i, n in enumerate(names):
                block = found[i * len(files):(i + 1) * len(files)]
                if cfg.doppler_sign is None:
                    cfgs[n] = replace(cfgs[n], doppler_sign=judge_sign(s for _, pair in block for s in pair))
                if cfg.depth_scale is None:
                    sign = cfgs[n].doppler_sign or 1
                    cal = depth_calibrations([e[sign] for e, _ in block])
                    cfgs[n] = replace(cfgs[n], depth_scale=tuple(c.scale for c in cal),
                                      depth_along_axis=tuple(c.along_axis for c in cal))
        tasks = [(f, n, replace(cfgs[n], cav=cav))
                 for n in names for cav in ("pipeline", "labels") for f in files]
        for k, r in enumerate(pool.map(_evaluate, tasks, chunksize=4)):
            results.append(r)
            if progress:
                progress(k + 1, len(tasks))
    n = len(files)
    out: dict = {"scenes": n, "checks": {}}
    for i, name in enumerate(names):
        check = CHECKS.get(name)
        entry = {"kind": check.kind if check else "reference",
                 "description": check.description if check else "the scenes as they are"}
        for j, cav in enumerate(("pipeline", "labels")):
            block = results[(2 * i + j) * n:(2 * i + j + 1) * n]
            entry[cav] = _summary(report(block, replace(cfg, cav=cav)))
            entry[cav]["changed_scenes"] = _changed(results[j * n:(j + 1) * n], block)
        entry["depth_scale"] = list(cfgs[name].depth_scale or (1.0, 1.0))
        entry["depth_along_axis"] = list(cfgs[name].depth_along_axis)
        out["checks"][name] = entry
    return out


class _Serial:
    """A stand-in for a process pool that maps in this process."""

    def __enter__(self) -> "_Serial":
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map(self, fn, items, chunksize: int = 1):
        return map(fn, items)


def markdown(result: dict) -> str:
    """The README table: per check, pair F1 and success with the pipeline and with perfect
    separation, the change from the unchanged scenes, how sure the pipeline's output stays
    (coverage, gross among the emitted, calibration error of its confidence), for invariances
    whether they hold, and the cameras' depth scales the check's scenes calibrated to."""
    ref = result["checks"][NONE]
    rows = ["| check | kind | pipeline F1 / success | labels F1 / success | pipeline F1 change (points) | "
            "pipeline coverage / gross among emitted / calibration error | "
            "scenes changed (pipeline / labels) | depth scale (Ego / CAV) |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, e in result["checks"].items():
        p, lab = e["pipeline"], e["labels"]
        delta = 100 * (p["pair_f1"] - ref["pipeline"]["pair_f1"])
        changed = f"{p['changed_scenes']} / {lab['changed_scenes']}"
        if e["kind"] == "invariance":
            changed += " (holds)" if p["changed_scenes"] == lab["changed_scenes"] == 0 else " (BROKEN)"
        scale = " / ".join(f"{x:.3f}" + (" (axis)" if a else "")
                           for x, a in zip(e.get("depth_scale", (1.0, 1.0)), e.get("depth_along_axis", (False, False))))
        rows.append(f"| {name} | {e['kind']} | {_figures(p)} | {_figures(lab)} | {delta:+.1f} | {_sureness(p)} | "
                    f"{changed} | {scale} |")
    return "\n".join(rows)


def _sureness(summary: dict) -> str:
    """ "coverage / gross among emitted / calibration error", or "-" without a scene."""
    if not summary["scenes"]:
        return "-"
    return f"{summary['coverage']:.2f} / {summary['gross_rate']:.3f} / {summary['calibration_error']:.3f}"


def _figures(summary: dict) -> str:
    """ "F1 / success", or "-" when no scene could be evaluated (no labels for perfect separation)."""
    if not summary["scenes"]:
        return "-"
    return f"{summary['pair_f1']:.3f} / {summary['success_rate']:.3f}"
