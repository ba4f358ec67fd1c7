"""How sure an estimate of T_ego_cav is: covariance, ambiguity, evidence, and a calibrated probability.

A driving stack can live with "no estimate"; it cannot live with a confident 36 m error.
After the aligner has its transform, `assess` measures what a wrong pose cannot fake and
turns it into the probability that the estimate lies within 2 m / 5 deg of the truth
(the success criterion of DESIGN.md):

- ambiguity: the best distinct alternative (more than 5 m or 10 deg away: the matcher's
  other hypotheses, a 180 deg flip about the matched vehicles, slides along the
  background's main direction) scored by the matcher's own evidence; its margin;
- mutual sighting: each vehicle sees the other where the estimate puts it;
- Doppler: each matched vehicle's radial speeds in the two views are explained by one
  plausible ground velocity (two lines of sight fix it);
- free space: the other radar's background must not lie where our radar sees through;
- the fit itself: matched-pair Mahalanobis residuals, background overlap both ways, how
  well the background pins the pose (covariance, and whether it all lies on one line),
  distance of the yaw to the nearest heading the two radars' velocities allow.
The covariance of (x, y, yaw) comes from the final fit's information matrix (matched
pairs with their line-of-sight covariances, point-to-line background terms counted as
independent per 2 m cell, the heading prior), inflated by the residuals and by a factor
calibrated on our own wide physics so that its 95 % ellipse holds the truth about 95 %
of the time. The probability is a logistic model over the evidence, fit on simulated
scenes of seeds not used for reporting (`mmatch fit-confidence`); its coefficients ship
as JSON beside this file.

Frames: the Ego radar frame, metres and radians; (x, y, yaw) are T_ego_cav's translation
and rotation about z.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from mmatch.ego.base import Hypotheses, MatchResult, heading_yaws, radial_ground_speeds
from mmatch.ego.observations import ObservationModel, Observations, mahalanobis, observe
from mmatch.errors import ConfigError
from mmatch.shared import SharedFrame

MODEL_PATH = Path(__file__).with_name("confidence_model.json")
CHI2_3_95 = 7.8147                  # 95 % quantile of chi-square with 3 degrees of freedom

FEATURES: tuple[str, ...] = (
    "n_pairs", "pair_chi2", "margin", "has_alternative", "sighting", "doppler_plausible",
    "doppler_tested", "free_space_violation", "bg_overlap", "bg_overlap_back", "log_pos_sigma",
    "log_yaw_sigma", "bg_linearity", "yaw_gap_deg", "n_background",
)
# which evidence a refusal names when it weighs most against the estimate
REASONS: dict[str, str] = {
    "n_pairs": "too few vehicles", "pair_chi2": "poor fit", "margin": "ambiguous",
    "has_alternative": "ambiguous", "sighting": "poor fit", "doppler_plausible": "poor fit",
    "doppler_tested": "too few vehicles", "free_space_violation": "poor fit", "bg_overlap": "poor fit",
    "bg_overlap_back": "poor fit", "log_pos_sigma": "symmetric background",
    "log_yaw_sigma": "symmetric background", "bg_linearity": "symmetric background",
    "yaw_gap_deg": "poor fit", "n_background": "too few vehicles",
}


@dataclass(frozen=True)
class ConfidenceConfig:
    """threshold: an estimate is "fused" only when its probability reaches this (else "no
    estimate" with the reason; None: the fitted model's threshold); distinct_m / distinct_deg: alternatives farther than this
    count as distinct; bg_sigma_m / bg_gate_m / bg_cell_m: background correspondence noise,
    gate and the cell size within which background terms count as one; heading_sigma_deg:
    the heading prior on the yaw; sighting_m / camera_half_fov_deg / camera_range_m /
    body_offset_m: where one vehicle expects to see the other (radar at the front bumper,
    body centre behind it); max_speed_mps: a ground velocity above this is implausible;
    slides_m: slide alternatives along the background's main direction; inflation: factor
    on the covariance (None: the fitted model's); model_path: the fitted probability
    model (None: the packaged one)."""

    threshold: float | None = None
    distinct_m: float = 5.0
    distinct_deg: float = 10.0
    bg_sigma_m: float = 0.5
    bg_gate_m: float = 1.0
    bg_cell_m: float = 2.0
    heading_sigma_deg: float = 3.0
    heading_gate_deg: float = 10.0
    sighting_m: float = 3.5
    camera_half_fov_deg: float = 30.0
    camera_range_m: float = 60.0
    body_offset_m: float = 2.3
    max_speed_mps: float = 40.0
    slides_m: tuple[float, ...] = (-30.0, -20.0, -12.0, -6.0, 6.0, 12.0, 20.0, 30.0)
    inflation: float | None = None
    model_path: str | None = None
    observation: ObservationModel = field(default_factory=ObservationModel)


@dataclass
class Assessment:
    """confidence: P(within 2 m / 5 deg) in 0-1; covariance (3, 3) of (x, y, yaw) in m, m, rad;
    ambiguity: the best distinct alternative's score relative to the estimate's (0 none,
    1 as good, > 1 better); reason: what weighs most against it; features: the evidence."""

    confidence: float
    covariance: np.ndarray
    ambiguity: float
    reason: str
    features: dict[str, float]


@dataclass(frozen=True)
class ProbabilityModel:
    """Logistic regression over standardised evidence (fit by `fit_model`)."""

    features: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    inflation: float = 1.0
    threshold: float = 0.5
    meta: dict = field(default_factory=dict)

    def logit_terms(self, x: np.ndarray) -> np.ndarray:
        return self.coef * (x - self.mean) / self.scale

    def probability(self, x: np.ndarray) -> np.ndarray:
        z = np.asarray(x, float)
        z = np.atleast_2d(z)
        s = ((z - self.mean) / self.scale) @ self.coef + self.intercept
        return 1.0 / (1.0 + np.exp(-np.clip(s, -40, 40)))

    def to_json(self) -> str:
        return json.dumps({"features": list(self.features), "mean": self.mean.tolist(),
                           "scale": self.scale.tolist(), "coef": self.coef.tolist(),
                           "intercept": float(self.intercept), "inflation": float(self.inflation),
                           "threshold": float(self.threshold), "meta": self.meta}, indent=1)

    @classmethod
    def from_json(cls, text: str, where: str = "<model>") -> "ProbabilityModel":
        try:
            d = json.loads(text)
            feats = tuple(d["features"])
            arrays = [np.asarray(d[k], float) for k in ("mean", "scale", "coef")]
            model = cls(feats, *arrays, float(d["intercept"]), float(d.get("inflation", 1.0)),
                        float(d.get("threshold", 0.5)), dict(d.get("meta", {})))
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{where}: not a confidence model ({exc})") from exc
        if feats != FEATURES or any(a.shape != (len(FEATURES),) for a in arrays) \
                or not all(np.all(np.isfinite(a)) for a in arrays) or np.any(model.scale <= 0):
            raise ConfigError(f"{where}: confidence model expects features {', '.join(FEATURES)}")
        return model


@lru_cache(maxsize=4)
def load_model(path: str | None = None) -> ProbabilityModel | None:
    """The probability model at `path` (None: the packaged one; None if it does not exist)."""
    p = Path(path) if path else MODEL_PATH
    if not p.is_file():
        if path:
            raise ConfigError(f"confidence model {p} does not exist")
        return None
    return ProbabilityModel.from_json(p.read_text(encoding="utf-8"), str(p))


def _rot(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _yaw(R: np.ndarray) -> np.ndarray:
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def _wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def pose_error(T_gt: np.ndarray, T_est: np.ndarray) -> np.ndarray:
    """(3,) error (x m, y m, yaw rad) of an estimate of T_ego_cav, Ego radar frame."""
    e = np.asarray(T_est, float)[:2, 3] - np.asarray(T_gt, float)[:2, 3]
    dyaw = _wrap(_yaw(np.asarray(T_est, float)[:2, :2]) - _yaw(np.asarray(T_gt, float)[:2, :2]))
    return np.array([e[0], e[1], float(dyaw)])


def inside_ellipse(error: np.ndarray, cov: np.ndarray, level: float = CHI2_3_95) -> bool:
    """Whether an (x, y, yaw) error lies inside the ellipse chi^2 <= level of cov."""
    try:
        return bool(error @ np.linalg.solve(cov, error) <= level)
    except np.linalg.LinAlgError:
        return False


def _normals(pts: np.ndarray, tree: cKDTree, k: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (N, 2) of a 2-D point set's local lines and their linearity (N,) in 0-1."""
    kk = min(k, len(pts))
    _, idx = tree.query(pts, k=kk)
    nb = pts[np.atleast_2d(idx)] if kk > 1 else pts[:, None]
    d = nb - nb.mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", d, d) / max(kk, 1)
    w, v = np.linalg.eigh(C)                                   # ascending
    normal = v[:, :, 0]
    lin = 1.0 - w[:, 0] / np.maximum(w[:, 1], 1e-9)
    return normal, np.clip(lin, 0.0, 1.0)


def information(own: SharedFrame, other: SharedFrame, A: Observations, B: Observations,
                R: np.ndarray, t: np.ndarray, pairs: np.ndarray, cfg: ConfidenceConfig
                ) -> tuple[np.ndarray, float, int, float]:
    """Information matrix (3, 3) of (x, y, yaw) at the estimate, the residual chi^2, its
    degrees of freedom and the mean matched-pair chi^2."""
    info = np.zeros((3, 3))
    chi2, dof, pair_chi2 = 0.0, 0, 0.0
    if len(pairs):
        dm = mahalanobis(A, B, R[None], t[None])[0][pairs[:, 0], pairs[:, 1]]
        for (i, j) in pairs:
            b = B.centres[j]
            S = A.cov[i] + R @ B.cov[j] @ R.T
            r = A.centres[i] - (R @ b + t)
            J = np.column_stack([np.eye(2), R @ np.array([-b[1], b[0]])])     # d(Rb + t)/d(x, y, yaw)
            W = np.linalg.inv(S)
            info += J.T @ W @ J
        pair_chi2 = float(np.mean(dm ** 2))
        chi2 += float(np.sum(np.minimum(dm ** 2, 25.0)))
        dof += 2 * len(pairs)
    bg_own, bg_other = own.background[:, :2].astype(float), other.background[:, :2].astype(float)
    if len(bg_own) >= 3 and len(bg_other) >= 3:
        tree = cKDTree(bg_own)
        moved = bg_other @ R.T + t
        d, k = tree.query(moved, distance_upper_bound=cfg.bg_gate_m)
        ok = np.isfinite(d)
        if ok.sum() >= 3:
            normal, lin = _normals(bg_own, tree)
            q, n, li = bg_own[k[ok]], normal[k[ok]], lin[k[ok]]
            src, mv = bg_other[ok], moved[ok]
            cells = np.unique(np.floor(mv / cfg.bg_cell_m).astype(np.int64), axis=0)
            w = len(cells) / len(src) / cfg.bg_sigma_m ** 2
            dpdyaw = np.column_stack([-src[:, 1], src[:, 0]]) @ R.T            # (M, 2)
            J = np.concatenate([np.broadcast_to(np.eye(2), (len(src), 2, 2)), dpdyaw[:, :, None]], axis=2)
            # point-to-line where the own background is a line, point-to-point where it is not
            P = li[:, None, None] * np.einsum("ni,nj->nij", n, n) + (1 - li)[:, None, None] * np.eye(2)
            info += w * np.einsum("nki,nkl,nlj->ij", J, P, J)
            r = q - mv
            chi2 += float(w * np.sum(np.einsum("ni,nij,nj->n", r, P, r)))
            dof += len(cells)
    yaws = heading_yaws(own, other)
    if yaws is not None:
        gap = np.abs(_wrap(_yaw(R) - yaws)).min()
        if gap < np.radians(cfg.heading_gate_deg):
            info[2, 2] += np.radians(cfg.heading_sigma_deg) ** -2
    return info, chi2, dof, pair_chi2


def covariance(info: np.ndarray, chi2: float, dof: int, inflation: float) -> np.ndarray:
    """(3, 3) covariance from an information matrix, inflated by the residuals (chi^2 / dof
    when above 1) and by `inflation`; unobserved directions get a huge variance."""
    reg = info + np.diag([1e-4, 1e-4, 1e-6])                 # a prior of 100 m / 1000 rad
    cov = np.linalg.inv(reg)
    s2 = max(1.0, chi2 / dof) if dof > 3 else 1.0
    return (cov + cov.T) / 2 * s2 * inflation


def _alternatives(R: np.ndarray, t: np.ndarray, A: Observations, B: Observations, pairs: np.ndarray,
                  bg_own: np.ndarray, hyp: Hypotheses | None, cfg: ConfidenceConfig
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Distinct alternative hypotheses (K, 2, 2), (K, 2): the matcher's, a flip, slides."""
    Rs, ts = [], []
    if hyp is not None and len(hyp.R):
        Rs.append(hyp.R)
        ts.append(hyp.t)
    # a 180 deg flip about the matched vehicles (or the other radar's position)
    pivot = A.centres[pairs[:, 0]].mean(axis=0) if len(pairs) else t
    Rf = R @ _rot(np.array(np.pi))
    Rs.append(Rf[None])
    ts.append((pivot - Rf @ (R.T @ (pivot - t)))[None])
    if len(bg_own) >= 3:                                       # slides along the main direction
        d = bg_own - bg_own.mean(axis=0)
        w, v = np.linalg.eigh(d.T @ d)
        axis = v[:, 1]
        sl = np.asarray(cfg.slides_m, float)
        Rs.append(np.repeat(R[None], len(sl), 0))
        ts.append(t[None] + sl[:, None] * axis[None])
    Ra, ta = np.concatenate(Rs), np.concatenate(ts)
    far = (np.linalg.norm(ta - t, axis=1) > cfg.distinct_m) \
        | (np.abs(_wrap(_yaw(Ra) - _yaw(R))) > np.radians(cfg.distinct_deg))
    return Ra[far], ta[far]


def _in_view(p: np.ndarray, cfg: ConfidenceConfig) -> np.ndarray:
    r = np.linalg.norm(p, axis=-1)
    az = np.abs(np.arctan2(p[..., 0], p[..., 1]))
    return (r > 4.0) & (r < cfg.camera_range_m) & (az < np.radians(cfg.camera_half_fov_deg))


def _sighting(A: Observations, B: Observations, R: np.ndarray, t: np.ndarray, cfg: ConfidenceConfig) -> float:
    """+1 per vehicle seen by the other where the estimate puts it, -1 per one expected but not seen."""
    body = np.array([0.0, -cfg.body_offset_m])
    out = 0.0
    cav_in_ego = R @ body + t
    if _in_view(cav_in_ego, cfg):
        seen = len(A.centres) and np.min(np.linalg.norm(A.centres - cav_in_ego, axis=1)) < cfg.sighting_m
        out += 1.0 if seen else -1.0
    ego_in_cav = R.T @ (body - t)
    if _in_view(ego_in_cav, cfg):
        seen = len(B.centres) and np.min(np.linalg.norm(B.centres - ego_in_cav, axis=1)) < cfg.sighting_m
        out += 1.0 if seen else -1.0
    return out


def two_view_velocities(own: SharedFrame, other: SharedFrame, R: np.ndarray, pairs: np.ndarray,
                        min_sin: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Ground velocity (P, 2) m/s, Ego frame, of each matched vehicle from its radial speeds in
    both views (NaN where a view has no points or the lines of sight are near-parallel), and
    whether it could be solved (P,)."""
    ge, ue = radial_ground_speeds(own)
    gc, uc = radial_ground_speeds(other)
    P = len(pairs)
    v = np.full((P, 2), np.nan)
    if P == 0:
        return v, np.zeros(0, bool)
    i, j = pairs[:, 0], pairs[:, 1]
    u1, u2 = ue[i], uc[j] @ R.T
    M = np.stack([u1, u2], axis=1)                            # (P, 2, 2) rows: lines of sight
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    ok = np.isfinite(det) & (np.abs(det) > min_sin) & np.isfinite(ge[i]) & np.isfinite(gc[j])
    if ok.any():
        v[ok] = np.linalg.solve(M[ok], np.column_stack([ge[i], gc[j]])[ok][..., None])[..., 0]
    return v, ok


def _free_space(own: SharedFrame, other: SharedFrame, R: np.ndarray, t: np.ndarray,
                bin_deg: float = 1.0, near_m: float = 2.0, margin_m: float = 3.0) -> float:
    """Share of the other background (within our view) that lies where our radar sees past it."""
    ours = np.vstack([own.background[:, :2], own.vehicle_points[:, :2]]).astype(float)
    theirs = other.background[:, :2].astype(float) @ R.T + t
    if len(ours) < 5 or len(theirs) < 5:
        return 0.0
    az_o, r_o = np.degrees(np.arctan2(ours[:, 0], ours[:, 1])), np.linalg.norm(ours, axis=1)
    az_t, r_t = np.degrees(np.arctan2(theirs[:, 0], theirs[:, 1])), np.linalg.norm(theirs, axis=1)
    lo, hi = az_o.min(), az_o.max()
    inside = (az_t >= lo) & (az_t <= hi) & (r_t > 3.0)
    if inside.sum() < 5:
        return 0.0
    nb = int(np.ceil((hi - lo) / bin_deg)) + 1
    bo = np.clip(((az_o - lo) / bin_deg).astype(int), 0, nb - 1)
    far = np.zeros(nb)
    np.maximum.at(far, bo, r_o)
    bt = np.clip(((az_t[inside] - lo) / bin_deg).astype(int), 0, nb - 1)
    tree = cKDTree(ours)
    d, _ = tree.query(theirs[inside], distance_upper_bound=near_m)
    beyond = far[bt] > r_t[inside] + margin_m
    return float(np.mean(beyond & ~np.isfinite(d)))


def evidence(own: SharedFrame, other: SharedFrame, T: np.ndarray, pairs: np.ndarray,
             match: MatchResult | None = None, scorer=None, cfg: ConfidenceConfig = ConfidenceConfig(),
             inflation: float = 1.0) -> tuple[dict[str, float], np.ndarray, float]:
    """The evidence features, the (x, y, yaw) covariance and the ambiguity of one estimate.

    scorer: callable (R (H, 2, 2), t (H, 2)) -> (H,) the matcher's evidence, or None.
    """
    R, t = np.asarray(T, float)[:2, :2], np.asarray(T, float)[:2, 3]
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    A, B = observe(own, cfg.observation), observe(other, cfg.observation)
    info, chi2, dof, pair_chi2 = information(own, other, A, B, R, t, pairs, cfg)
    cov = covariance(info, chi2, dof, inflation)
    bg_own, bg_other = own.background[:, :2].astype(float), other.background[:, :2].astype(float)

    margin, has_alt, ambiguity = 1.0, 0.0, 0.0
    if scorer is not None:
        Ra, ta = _alternatives(R, t, A, B, pairs, bg_own, match.hypotheses if match else None, cfg)
        s = scorer(np.concatenate([R[None], Ra]), np.concatenate([t[None], ta]))
        best, alt = float(s[0]), (float(np.max(s[1:])) if len(s) > 1 else -np.inf)
        if np.isfinite(alt):
            has_alt = 1.0
            margin = float(np.clip((best - alt) / (abs(best) + 1.0), -1.0, 1.0))
            ambiguity = float(np.clip(alt / best, 0.0, 2.0)) if best > 0 else 2.0
    v2, solved = two_view_velocities(own, other, R, pairs)
    speed = np.linalg.norm(v2, axis=1)
    plausible = float(np.mean(speed[solved] < cfg.max_speed_mps)) if solved.any() else 0.5
    overlap, back = 0.0, 0.0
    if len(bg_own) >= 3 and len(bg_other) >= 3:
        d, _ = cKDTree(bg_own).query(bg_other @ R.T + t, distance_upper_bound=cfg.bg_gate_m)
        overlap = float(np.isfinite(d).mean())
        d, _ = cKDTree(bg_other).query((bg_own - t) @ R, distance_upper_bound=cfg.bg_gate_m)
        back = float(np.isfinite(d).mean())
    both = np.vstack([bg_own, bg_other @ R.T + t]) if len(bg_other) else bg_own
    lin = 1.0
    if len(both) >= 3:
        ev = np.linalg.eigvalsh(np.cov(both.T))
        lin = float(ev[0] / max(ev[1], 1e-9))
    yaws = heading_yaws(own, other)
    gap = float(np.degrees(np.abs(_wrap(_yaw(R) - yaws)).min())) if yaws is not None else 45.0
    feats = {
        "n_pairs": float(min(len(pairs), 8)),
        "pair_chi2": float(min(pair_chi2, 25.0)),
        "margin": margin,
        "has_alternative": has_alt,
        "sighting": _sighting(A, B, R, t, cfg),
        "doppler_plausible": plausible,
        "doppler_tested": float(min(int(solved.sum()), 4)),
        "free_space_violation": _free_space(own, other, R, t),
        "bg_overlap": overlap,
        "bg_overlap_back": back,
        "log_pos_sigma": float(np.log(np.sqrt(max(cov[0, 0] + cov[1, 1], 1e-9)) / max(inflation, 1e-9) ** 0.5)),
        "log_yaw_sigma": float(np.log(np.sqrt(max(cov[2, 2], 1e-12)) / max(inflation, 1e-9) ** 0.5)),
        "bg_linearity": lin,
        "yaw_gap_deg": min(gap, 45.0),
        "n_background": float(np.log1p(min(len(bg_own), len(bg_other)))),
    }
    return feats, cov, ambiguity


def threshold(cfg: ConfidenceConfig = ConfidenceConfig()) -> float:
    """The probability below which an estimate is refused (0 without a model)."""
    if cfg.threshold is not None:
        return float(cfg.threshold)
    model = load_model(cfg.model_path)
    return model.threshold if model is not None else 0.0


def assess(own: SharedFrame, other: SharedFrame, T: np.ndarray, pairs: np.ndarray,
           match: MatchResult | None = None, scorer=None, cfg: ConfidenceConfig = ConfidenceConfig()
           ) -> Assessment:
    """Confidence, covariance, ambiguity and the reason against one estimate (see the module doc).

    Without a fitted model the probability is NaN (nothing is refused).
    """
    model = load_model(cfg.model_path)
    inflation = cfg.inflation if cfg.inflation is not None else (model.inflation if model else 1.0)
    feats, cov, ambiguity = evidence(own, other, T, pairs, match, scorer, cfg, inflation)
    if model is None:
        return Assessment(float("nan"), cov, ambiguity, "", feats)
    x = np.array([feats[k] for k in FEATURES])
    p = float(model.probability(x)[0])
    terms = model.logit_terms(x)
    reason = REASONS[FEATURES[int(np.argmin(terms))]]
    return Assessment(p, cov, ambiguity, reason, feats)
