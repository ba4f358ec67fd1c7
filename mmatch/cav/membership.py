"""Which radar points belong to which camera box, learned: a small network on (point, box) pairs.

The fixed frustum tests (frustum.py) decide from one feature at a time: inside the box's
columns or not, inside a depth window or not, moving or not. Under real angle noise (a
degree or two, more at low SNR), glint, wheels and false detections that is too blunt: on
wide-physics scenes it shared 10 % foreign points and missed 18 % of a vehicle's own. Here
every point near a box (within 4 azimuth standard deviations of its columns, inside a wide
depth window) is a candidate, described by how far it lies outside the box in its own angle
accuracy, its depth gap, its Doppler against the stationary world and against the box's
other moving candidates, its SNR, how compact it sits with the box's other candidates in
range, and how many boxes compete for it. A two-layer perceptron (numpy forward pass;
weights fit by `fit_membership` on simulated scenes with labels, shipped as JSON beside this
file) gives the probability that the point is the box's vehicle's; each point goes to the
box it most probably belongs to, above a threshold, or to none.

A second perceptron (the context stage, when the model file has one) then judges each candidate
again against its box's core, the candidates the first stage gave the box: how far the point lies
from the core's nearest return and from its median range, how far beyond its near face, whether
its Doppler residual lies in the box's wheel band (a wheel's surface moves at 0 ... 2 x the body's
speed), and how big the box is in metres (trucks are long). The first stage alone has to judge a
point by itself, so it let go of wheel returns and the far parts of long vehicles, which the
DBSCAN main cluster dropped again: on 200 wide hard scenes (seed 2) the pipeline kept 80 % of
the vehicles' own returns and placed 18 % of the vehicles more than 1 m from where their
labelled returns put them. With the context stage in place of that DBSCAN step: 90 % and 11 %.

Frames: points in the radar frame (m, m/s, dB); boxes in pixels with depth in metres.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from mmatch.cav.accuracy import RadarAccuracyConfig, sigma_azimuth, stationary_doppler_sigma
from mmatch.cav.frustum import Projection
from mmatch.errors import ConfigError
from mmatch.numeric import lengths, median
from mmatch.shared import lifted_scores
from mmatch.types import CameraModel

MODEL_PATH = Path(__file__).with_name("membership_model.json")
FEATURES: tuple[str, ...] = (
    "abs_depth_gap_rel", "depth_gap_rel", "abs_column_offset", "outside_columns_sigma", "abs_row_offset",
    "moving", "residual_sigma", "residual_vs_box_sigma", "box_moving_share", "boxes_claiming",
    "log_depth", "range_vs_box_median_m",
)
# Left out on purpose: the SNR itself, the box score, the angle sigma as a number. Their
# distributions are one simulator's (vehicles brighter than the roadside, a detector's score
# calibration); a model that leaned on them lost 40 % of the vehicle points on frames of
# another generator. They enter only as normalisers (outside_columns_sigma, residual_sigma).
CONTEXT_FEATURES: tuple[str, ...] = (
    "core_distance_m", "core_range_gap_m", "beyond_near_face_m", "outside_wheel_band_sigma", "core_size",
    "first_probability", "box_width_m", "box_height_m", "core_residual_gap_sigma",
)
CONTEXT_CAP_M = 20.0             # distances of the context stage are capped here (and given this without a core)
MAX_OUTSIDE_SIGMA = 4.0          # candidates lie within this many azimuth sigmas of the box's columns
DEPTH_WINDOW_REL, DEPTH_WINDOW_M = 0.45, 3.0


@dataclass(frozen=True)
class MembershipModel:
    """A two-layer perceptron over standardised features: p = sigmoid(w3 . relu(W2 relu(W1 x + b1) + b2) + b3).

    features: what it reads (FEATURES; its context stage FEATURES + CONTEXT_FEATURES);
    context: the second stage (see the module docstring) or None; box: the false-detection model.
    """

    mean: np.ndarray
    scale: np.ndarray
    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    threshold: float = 0.5
    meta: dict | None = None
    box: "BoxModel | None" = None
    context: "MembershipModel | None" = None
    features: tuple[str, ...] = FEATURES

    def probability(self, X: np.ndarray) -> np.ndarray:
        h = (np.asarray(X, np.float64) - self.mean) / self.scale
        for k, (W, b) in enumerate(self.layers):
            h = h @ W + b
            if k < len(self.layers) - 1:
                h = np.maximum(h, 0.0)
        return 1.0 / (1.0 + np.exp(-np.clip(h[:, 0], -40, 40)))

    def to_dict(self) -> dict:
        out = {"features": list(self.features), "mean": self.mean.tolist(), "scale": self.scale.tolist(),
               "layers": [[W.tolist(), b.tolist()] for W, b in self.layers],
               "threshold": self.threshold, "meta": self.meta or {}}
        if self.box is not None:
            out["box"] = self.box.to_dict()
        if self.context is not None:
            out["context"] = self.context.to_dict()
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text: str, where: str = "<model>") -> "MembershipModel":
        try:
            d = json.loads(text)
        except ValueError as exc:
            raise ConfigError(f"{where}: not a membership model ({exc})") from exc
        return cls.from_dict(d, where)

    @classmethod
    def from_dict(cls, d: dict, where: str = "<model>", features: tuple[str, ...] = FEATURES,
                  key: str = "membership model") -> "MembershipModel":
        try:
            layers = tuple((np.asarray(W, float), np.asarray(b, float)) for W, b in d["layers"])
            box = BoxModel.from_dict(d["box"]) if "box" in d else None
            context = cls.from_dict(d["context"], where, features + CONTEXT_FEATURES, "membership model's context") \
                if "context" in d else None
            model = cls(np.asarray(d["mean"], float), np.asarray(d["scale"], float), layers,
                        float(d.get("threshold", 0.5)), dict(d.get("meta", {})), box, context, features)
            feats = tuple(d["features"])
        except ConfigError:
            raise
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ConfigError(f"{where}: not a {key} ({exc})") from exc
        dims = [len(features)] + [W.shape[1] if W.ndim == 2 else -1 for W, _ in layers]
        ok = feats == features and model.mean.shape == model.scale.shape == (len(features),) \
            and all(W.ndim == 2 and W.shape == (dims[k], dims[k + 1]) and b.shape == (dims[k + 1],)
                    for k, (W, b) in enumerate(layers)) and dims[-1] == 1
        if not ok:
            raise ConfigError(f"{where}: {key} expects features {', '.join(features)}")
        return model


@dataclass(frozen=True)
class BoxModel:
    """Logistic regression of "this box is a vehicle" over BOX_FEATURES (standardised); boxes
    below `threshold` are not shared. 0.15 by default: on the tuning seed it kept pair F1 best
    for both matchers together (RM-net handles most false detections itself and loses more by
    a real box dropped: 0.804 at 0.15 against 0.791 at 0.3; consensus 0.774 against 0.786)."""

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    threshold: float = 0.15

    def probability(self, X: np.ndarray) -> np.ndarray:
        z = ((np.asarray(X, np.float64) - self.mean) / self.scale) @ self.coef + self.intercept
        return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))

    def to_dict(self) -> dict:
        return {"features": list(BOX_FEATURES), "mean": self.mean.tolist(), "scale": self.scale.tolist(),
                "coef": self.coef.tolist(), "intercept": self.intercept, "threshold": self.threshold}

    @classmethod
    def from_dict(cls, d: dict) -> "BoxModel":
        if tuple(d["features"]) != BOX_FEATURES:
            raise ValueError(f"box model expects features {', '.join(BOX_FEATURES)}")
        arrays = [np.asarray(d[k], float) for k in ("mean", "scale", "coef")]
        if any(a.shape != (len(BOX_FEATURES),) for a in arrays):
            raise ValueError("box model arrays have the wrong shape")
        return cls(*arrays, float(d["intercept"]), float(d.get("threshold", 0.3)))


@lru_cache(maxsize=4)
def load_model(path: str | None = None) -> MembershipModel | None:
    """The model at `path` (None: the packaged one, or None when there is none)."""
    p = Path(path) if path else MODEL_PATH
    if not p.is_file():
        if path:
            raise ConfigError(f"membership model {p} does not exist")
        return None
    return MembershipModel.from_json(p.read_text(encoding="utf-8"), str(p))


@dataclass
class Candidates:
    """(point, box) candidate pairs of one frame: point index (C,), box index (C,), features (C, F)."""

    point: np.ndarray
    box: np.ndarray
    features: np.ndarray


def candidates(points: np.ndarray, boxes: np.ndarray, camera: CameraModel, proj: Projection,
               residual: np.ndarray, moving: np.ndarray, velocity: np.ndarray | None,
               accuracy: RadarAccuracyConfig = RadarAccuracyConfig(),
               doppler_sigma: np.ndarray | None = None,
               azimuth_sigma: np.ndarray | None = None) -> Candidates:
    """Every point near every box, with the features the model reads (see FEATURES).

    residual / moving: from the ego-motion fit (zeros / False without an estimate);
    velocity: the fitted radar velocity (vx, vy) or None; doppler_sigma: (N,) the points'
    `stationary_doppler_sigma` under it, azimuth_sigma: (N,) their `sigma_azimuth` (rad),
    each when the caller has it already.
    """
    n, m = len(points), len(boxes)
    empty = Candidates(np.zeros(0, int), np.zeros(0, int), np.zeros((0, len(FEATURES))))
    if n == 0 or m == 0:
        return empty
    b = np.asarray(boxes, np.float64)
    fx = float(camera.K[0, 0])
    sig = sigma_azimuth(points, accuracy) if azimuth_sigma is None else azimuth_sigma
    if doppler_sigma is not None:
        sd = doppler_sigma
    else:
        sd = stationary_doppler_sigma(points, velocity, accuracy) if velocity is not None else np.ones(n)
    u, v = proj.uv[:, 0:1], proj.uv[:, 1:2]
    uc, hw = (b[:, 0] + b[:, 2]) / 2, np.maximum((b[:, 2] - b[:, 0]) / 2, 1.0)
    vc, hh = (b[:, 1] + b[:, 3]) / 2, np.maximum((b[:, 3] - b[:, 1]) / 2, 1.0)
    with np.errstate(invalid="ignore"):
        out_u = np.maximum(np.abs(u - uc) - hw, 0.0) / (fx * np.maximum(sig, 1e-3))[:, None]
        gap = (proj.bev_range[:, None] - b[None, :, 5]) / b[None, :, 5]
        near = proj.front[:, None] & (out_u <= MAX_OUTSIDE_SIGMA) \
            & (np.abs(gap) <= DEPTH_WINDOW_REL + DEPTH_WINDOW_M / b[None, :, 5])
    ii, jj = np.nonzero(near)
    if len(ii) == 0:
        return empty
    res = np.asarray(residual, np.float64)
    mov = np.asarray(moving, bool)
    claims = near.sum(axis=1)
    mov_c = near & mov[:, None]
    n_c = np.maximum(near.sum(axis=0), 1)
    box_moving = mov_c.sum(axis=0) / n_c
    box_motion = np.zeros(m)
    box_range = b[:, 5].copy()
    for k in np.flatnonzero(near.any(axis=0)):
        sel = near[:, k]
        box_range[k] = median(proj.bev_range[sel])
        if mov_c[:, k].any():
            box_motion[k] = median(res[mov_c[:, k]])
    F = np.column_stack([
        np.abs(gap[ii, jj]), gap[ii, jj],
        np.abs(u[ii, 0] - uc[jj]) / hw[jj], out_u[ii, jj],
        np.nan_to_num(np.abs(v[ii, 0] - vc[jj]) / hh[jj], nan=10.0),
        mov[ii].astype(float), np.abs(res[ii]) / np.maximum(sd[ii], 0.05),
        np.abs(res[ii] - box_motion[jj]) / np.maximum(sd[ii], 0.3),
        box_moving[jj], claims[ii].astype(float),
        np.log(np.maximum(b[jj, 5], 0.5)), np.abs(proj.bev_range[ii] - box_range[jj]),
    ])
    return Candidates(ii, jj, np.nan_to_num(F, nan=0.0, posinf=1e3, neginf=-1e3))


@dataclass(frozen=True)
class CandidateScene:
    """What the context stage reads beside the candidates, all of one frame: points (N, 5) and
    their projection, Doppler residuals against the stationary world (N,) m/s and their
    stationary standard deviations (N,) m/s, boxes (M, 6) and the camera."""

    points: np.ndarray
    proj: Projection
    residual: np.ndarray
    doppler_sigma: np.ndarray
    boxes: np.ndarray
    camera: CameraModel


def context_features(cands: Candidates, prob: np.ndarray, owner: np.ndarray, scene: CandidateScene) -> np.ndarray:
    """(C, len(CONTEXT_FEATURES)) each candidate against its box's core: the candidates the first
    stage (probabilities `prob` (C,), assignment `owner` (N,)) gave that box with p >= 0.5.

    Distances in metres (capped at CONTEXT_CAP_M, which a box without a core gets), ranges
    from the radar; the wheel band and the residual gap in standard deviations of the point's
    stationary Doppler (at least 0.3 m/s); box width and height in metres at the box depth.
    """
    C = len(cands.point)
    F = np.zeros((C, len(CONTEXT_FEATURES)))
    if C == 0:
        return F
    cap = CONTEXT_CAP_M
    b = np.asarray(scene.boxes, np.float64)
    xy = np.asarray(scene.points[:, :2], np.float64)
    rng = scene.proj.bev_range
    res = np.asarray(scene.residual, np.float64)
    sd = np.maximum(np.asarray(scene.doppler_sigma, np.float64), 0.3)
    in_core = (owner[cands.point] == cands.box) & (prob >= 0.5)
    F[:, 5] = prob
    F[:, 6] = (b[cands.box, 2] - b[cands.box, 0]) * b[cands.box, 5] / float(scene.camera.K[0, 0])
    F[:, 7] = (b[cands.box, 3] - b[cands.box, 1]) * b[cands.box, 5] / float(scene.camera.K[1, 1])
    for k in np.unique(cands.box):
        sel = np.flatnonzero(cands.box == k)
        core = cands.point[sel[in_core[sel]]]
        F[sel, 4] = len(core)
        if len(core) == 0:
            F[sel, :3] = cap
            continue
        pts = cands.point[sel]
        d = lengths(xy[pts][:, None] - xy[core][None])
        d[pts[:, None] == core[None]] = np.inf                    # not the point itself
        F[sel, 0] = np.minimum(d.min(axis=1), cap)
        F[sel, 1] = np.minimum(np.abs(rng[pts] - median(rng[core])), cap)
        F[sel, 2] = np.clip(rng[pts] - rng[core].min(), -cap, cap)
        body = float(median(res[core]))
        lo, hi = min(0.0, 2 * body), max(0.0, 2 * body)
        F[sel, 3] = (np.maximum(lo - res[pts], 0.0) + np.maximum(res[pts] - hi, 0.0)) / sd[pts]
        F[sel, 8] = np.abs(res[pts] - body) / sd[pts]
    return np.nan_to_num(F, nan=0.0, posinf=cap, neginf=-cap)


def assign(cands: Candidates, n_points: int, model: MembershipModel, threshold: float | None = None,
           scene: CandidateScene | None = None) -> tuple[np.ndarray, np.ndarray]:
    """owner (N,): the box each point most probably belongs to, above the threshold, else -1;
    and each candidate's probability (C,). With `scene` and a model with a context stage, the
    second stage's (threshold: the first stage's only)."""
    if len(cands.point) == 0:
        return np.full(n_points, -1, np.int32), np.zeros(0)
    p = model.probability(cands.features)
    owner = _most_probable(cands, n_points, p, model.threshold if threshold is None else threshold)
    if model.context is not None and scene is not None:
        p = model.context.probability(np.hstack([cands.features, context_features(cands, p, owner, scene)]))
        owner = _most_probable(cands, n_points, p, model.context.threshold)
    return owner, p


def _most_probable(cands: Candidates, n_points: int, p: np.ndarray, threshold: float) -> np.ndarray:
    owner = np.full(n_points, -1, np.int32)
    order = np.lexsort((p, cands.point))                     # per point, ascending probability
    last = np.ones(len(order), bool)
    last[:-1] = cands.point[order][1:] != cands.point[order][:-1]
    top = order[last]                                         # each point's most probable box
    ok = p[top] > threshold
    owner[cands.point[top[ok]]] = cands.box[top[ok]]
    return owner


def _labelled_candidates(views: list, accuracy: RadarAccuracyConfig, egomotion=None, labels: bool = True):
    """(view, candidates, the context stage's inputs or None) of each usable view (`View`s with
    box ids, and point labels when `labels`), and the view's ego-motion fit and projection."""
    from mmatch.cav.config import EgoMotionConfig
    from mmatch.cav.egomotion import fit_egomotion
    from mmatch.cav.frustum import project

    for v in views:
        if v.box_ids is None or (labels and v.point_labels is None) or len(v.points) == 0 or len(v.boxes) == 0:
            continue
        ego = fit_egomotion(v.points, egomotion or EgoMotionConfig(), accuracy)
        pr = project(v.points[:, :3], v.camera)
        sd = stationary_doppler_sigma(v.points, ego.velocity, accuracy) if ego.ok else None
        c = candidates(v.points, v.boxes, v.camera, pr, ego.residual, ego.moving,
                       ego.velocity if ego.ok else None, accuracy, sd)
        # the context stage runs only with an ego-motion estimate, as at run time
        scene = CandidateScene(v.points, pr, ego.residual, sd, v.boxes, v.camera) if ego.ok else None
        yield v, c, scene, ego, pr


def labelled_candidates(views: list, accuracy: RadarAccuracyConfig = RadarAccuracyConfig(),
                        egomotion=None) -> list[tuple]:
    """`_labelled_candidates` of views with box ids, computed once for the three fits of
    `mmatch fit-separation` (training_pairs, context_training_pairs, box_training_rows take it
    as `prepared`; each would otherwise redo every view's ego-motion fit and candidates)."""
    return list(_labelled_candidates(views, accuracy, egomotion, labels=False))


def _prepared(views: list, accuracy: RadarAccuracyConfig, egomotion, prepared: list | None, labels: bool):
    rows = prepared if prepared is not None else _labelled_candidates(views, accuracy, egomotion, labels)
    return (r for r in rows if not labels or r[0].point_labels is not None)


def _truth(v, c: Candidates) -> np.ndarray:
    return (v.point_labels[c.point] == v.box_ids[c.box]) & (v.box_ids[c.box] >= 0)


def training_pairs(views: list, accuracy: RadarAccuracyConfig = RadarAccuracyConfig(),
                   egomotion=None, prepared: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Features (C, F) and truth (C,) of every candidate pair of labelled views (`View`s with
    point_labels and box_ids): a pair is true when the point's label is the box's vehicle.
    prepared: `labelled_candidates(views, ...)` when the caller has it."""
    Xs, ys = [], []
    for v, c, _, _, _ in _prepared(views, accuracy, egomotion, prepared, labels=True):
        Xs.append(c.features)
        ys.append(_truth(v, c))
    X = np.vstack(Xs) if Xs else np.zeros((0, len(FEATURES)))
    return X, np.concatenate(ys) if ys else np.zeros(0, bool)


def context_training_pairs(views: list, model: MembershipModel,
                           accuracy: RadarAccuracyConfig = RadarAccuracyConfig(),
                           egomotion=None, prepared: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The context stage's features (C, F + CF) under `model`'s first stage, and truth (C,), of
    the candidates of labelled views with an ego-motion estimate (prepared: as training_pairs)."""
    first = replace(model, context=None)
    Xs, ys = [], []
    for v, c, scene, _, _ in _prepared(views, accuracy, egomotion, prepared, labels=True):
        if scene is None or len(c.point) == 0:
            continue
        owner, p = assign(c, len(v.points), first)
        Xs.append(np.hstack([c.features, context_features(c, p, owner, scene)]))
        ys.append(_truth(v, c))
    X = np.vstack(Xs) if Xs else np.zeros((0, len(FEATURES) + len(CONTEXT_FEATURES)))
    return X, np.concatenate(ys) if ys else np.zeros(0, bool)


def box_training_rows(views: list, model: MembershipModel, accuracy: RadarAccuracyConfig = RadarAccuracyConfig(),
                      prepared: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Box features (B, len(BOX_FEATURES)) under `model`'s assignment, and truth (B,): a real
    vehicle (prepared: as training_pairs)."""
    Xs, ys = [], []
    for v, c, scene, ego, pr in _prepared(views, accuracy, None, prepared, labels=False):
        owner, p = assign(c, len(v.points), model, scene=scene)
        Xs.append(box_features(c, p, owner, ego.moving, v.boxes, v.camera, pr))
        ys.append(v.box_ids >= 0)
    X = np.vstack(Xs) if Xs else np.zeros((0, len(BOX_FEATURES)))
    return X, np.concatenate(ys) if ys else np.zeros(0, bool)


def fit_box_model(X: np.ndarray, y: np.ndarray, threshold: float = 0.15) -> BoxModel:
    """Logistic regression of real vehicle against false detection (scikit-learn, L2)."""
    from sklearn.linear_model import LogisticRegression

    if len(X) < 20 or y.all() or not y.any():
        raise ValueError(f"need at least 20 boxes with both outcomes, got {len(X)}")
    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    clf = LogisticRegression(max_iter=5000).fit((X - mean) / scale, y)
    return BoxModel(mean, scale, clf.coef_[0].astype(float), float(clf.intercept_[0]), threshold)


def fit_membership(X: np.ndarray, y: np.ndarray, hidden: tuple[int, ...] = (32, 16), seed: int = 0,
                   threshold: float = 0.5, meta: dict | None = None,
                   features: tuple[str, ...] = FEATURES) -> MembershipModel:
    """Train the perceptron (scikit-learn, early stopping on a 10 % validation split); `features`
    names X's columns (FEATURES + CONTEXT_FEATURES for a context stage)."""
    from sklearn.neural_network import MLPClassifier

    if len(X) < 100 or y.all() or not y.any():
        raise ValueError(f"need at least 100 candidate pairs with both outcomes, got {len(X)}")
    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    clf = MLPClassifier(hidden, max_iter=300, random_state=seed, early_stopping=True)
    clf.fit((X - mean) / scale, y)
    layers = tuple((np.asarray(W, float), np.asarray(b, float)) for W, b in zip(clf.coefs_, clf.intercepts_))
    info = dict(meta or {}, pairs=int(len(X)), true_share=float(y.mean()), hidden=list(hidden), seed=seed,
                validation_score=float(clf.best_validation_score_))
    return MembershipModel(mean, scale, layers, threshold, info, features=features)


BOX_FEATURES: tuple[str, ...] = (
    "score", "score_vs_frame_median", "log_depth", "points", "moving_points", "best_probability", "mean_top3_probability",
    "candidates", "see_through", "inside_better_box", "metric_width_m", "metric_height_m", "aspect",
    "at_image_edge",
)


def box_features(cands: Candidates, prob: np.ndarray, owner: np.ndarray, moving: np.ndarray, boxes: np.ndarray,
                 camera: CameraModel, proj: Projection) -> np.ndarray:
    """(M, len(BOX_FEATURES)) what the radar and the box itself say about each box being a vehicle:
    its score (lifted to a frame median of at least 0.8, shared.lifted_scores), how many returns
    it won and how sure, whether the radar sees past it, whether it lies inside a better box, and
    how big it is in metres at its depth."""
    m = len(boxes)
    b = np.asarray(boxes, np.float64)
    F = np.zeros((m, len(BOX_FEATURES)))
    if m == 0:
        return F
    fx, fy = float(camera.K[0, 0]), float(camera.K[1, 1])
    w, h = np.maximum(b[:, 2] - b[:, 0], 1.0), np.maximum(b[:, 3] - b[:, 1], 1.0)
    mine = owner >= 0
    pts = np.bincount(owner[mine], minlength=m)[:m]
    mov = np.bincount(owner[mine & moving], minlength=m)[:m]
    best = np.zeros(m)
    top3 = np.zeros(m)
    ncand = np.bincount(cands.box, minlength=m)[:m] if len(cands.box) else np.zeros(m)
    for k in np.unique(cands.box):
        pk = np.sort(prob[cands.box == k])[::-1]
        best[k], top3[k] = pk[0], pk[:3].mean()
    see = np.zeros(m)
    if len(proj.uv):
        u = proj.uv[:, 0:1]
        with np.errstate(invalid="ignore"):
            cols = proj.front[:, None] & (u >= b[None, :, 0]) & (u <= b[None, :, 2])
        see = (cols & (proj.bev_range[:, None] > b[None, :, 5] * 1.3 + 4.0)).sum(axis=0)
    area = w * h
    iw = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1]), 0, None)
    inside = iw * ih / area[:, None]
    better = b[None, :, 4] > b[:, None, 4]
    np.fill_diagonal(inside, 0.0)
    edge = (b[:, 0] <= 2) | (b[:, 2] >= camera.image_size[0] - 3)
    F[:] = np.column_stack([lifted_scores(b[:, 4]), b[:, 4] / max(float(median(b[:, 4])), 1e-3),
                            np.log(np.maximum(b[:, 5], 0.5)), pts, mov, best, top3, ncand,
                            np.log1p(see), np.where(better, inside, 0.0).max(axis=1), w * b[:, 5] / fx,
                            h * b[:, 5] / fy, w / h, edge.astype(float)])
    return F
