"""Radar ego-motion from Doppler: which points are stationary, which move (DESIGN.md conventions).

A stationary target seen from a radar moving with velocity (vx, vy) over ground (radar
frame, x right, y forward) has radial velocity

    doppler = -(vx * sin(az) + vy * cos(az)) * cos(el),   az = atan2(x, y),  el = atan2(z, hypot(x, y)),

i.e. `doppler = A @ v` with the row `A = -cos(el) * [sin(az), cos(az)]`. Two points at different
bearings fix v; RANSAC draws all 2-point hypotheses at once, scores them with a truncated
quadratic (MSAC) and the best one seeds a weighted least-squares refit on its inliers.
Points whose residual exceeds the (bearing-dependent) threshold are moving.

With `threshold_sigma` > 0 a second pass sizes each point's threshold from what the
radar can know of it (cav/accuracy.py): its Doppler noise and its azimuth error times
how fast the stationary Doppler changes with azimuth at the fitted velocity, both from
its SNR. A weak point off boresight at speed gets a wide threshold (a parked car's
returns at 8 dB no longer look like moving ones), a strong one near boresight a narrow
one (a slow vehicle there still moves).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import Enum

import numpy as np

from mmatch.cav.accuracy import RadarAccuracyConfig, stationary_doppler_sigma
from mmatch.cav.config import EgoMotionConfig
from mmatch.types import DOPPLER, X, Y, Z

log = logging.getLogger(__name__)


class EgoStatus(str, Enum):
    """Outcome of a fit; anything but OK means `velocity` is NaN and no point is called moving."""

    OK = "ok"
    TOO_FEW_POINTS = "too-few-points"
    DEGENERATE_BEARING = "degenerate-bearing"
    NO_CONSENSUS = "no-consensus"


@dataclass
class EgoMotion:
    """Result of `fit_egomotion` for one frame of N points.

    velocity: float64 (2,) radar velocity over ground (vx, vy), m/s, radar frame; NaN when
        status is not OK.
    residual: float32 (N,) doppler - predicted stationary doppler, m/s (0 when no estimate).
    threshold: float32 (N,) the per-point stationary threshold used, m/s.
    moving: bool (N,) |residual| > threshold (all False when no estimate).
    status: EgoStatus; reason: human-readable detail.
    inliers: number of stationary points used in the final least squares.
    """

    velocity: np.ndarray
    residual: np.ndarray
    threshold: np.ndarray
    moving: np.ndarray
    status: EgoStatus
    reason: str = ""
    inliers: int = 0

    @property
    def ok(self) -> bool:
        return self.status is EgoStatus.OK


def design_rows(points: np.ndarray) -> np.ndarray:
    """Rows A (N, 2) of the stationary model doppler = A @ (vx, vy) for (N, >=3) points x, y, z."""
    x = points[:, X].astype(np.float64)
    y = points[:, Y].astype(np.float64)
    z = points[:, Z].astype(np.float64)
    rh = np.hypot(x, y)
    inv = 1.0 / np.maximum(np.hypot(rh, z), 1e-9)
    # -cos(el) * sin(az) = -x / r ; -cos(el) * cos(az) = -y / r   (r the 3-D range)
    return np.column_stack([-x * inv, -y * inv])


def stationary_doppler(points: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Doppler (N,) m/s that stationary targets at `points` show to a radar moving at `velocity`."""
    return design_rows(points) @ np.asarray(velocity, np.float64)


def point_threshold(points: np.ndarray, config: EgoMotionConfig) -> np.ndarray:
    """Per-point stationary threshold (N,) m/s, growing off boresight like the Doppler noise."""
    az = np.arctan2(points[:, X], points[:, Y]).astype(np.float64)
    grow = np.clip(np.abs(az) / np.radians(config.edge_az_deg), 0.0, 1.0) ** 2
    return config.threshold_mps + config.threshold_growth_mps * grow


def _no_estimate(n: int, status: EgoStatus, reason: str, thr: np.ndarray | None = None) -> EgoMotion:
    log.debug("ego-motion: no estimate (%s: %s)", status.value, reason)
    return EgoMotion(velocity=np.full(2, np.nan), residual=np.zeros(n, np.float32),
                     threshold=np.zeros(n, np.float32) if thr is None else thr.astype(np.float32),
                     moving=np.zeros(n, bool), status=status, reason=reason)


def _weighted_lstsq(A: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Solve min sum w_i (A_i v - d_i)^2 for v (2,) with the 2x2 normal equations."""
    Aw = A * w[:, None]
    N = Aw.T @ A
    return np.linalg.solve(N, Aw.T @ d)


def _bearing_spread_deg(A: np.ndarray) -> float:
    az = np.arctan2(-A[:, 0], -A[:, 1])
    return float(np.degrees(np.ptp(az))) if len(az) else 0.0


def fit_egomotion(points: np.ndarray, config: EgoMotionConfig | None = None,
                  accuracy: RadarAccuracyConfig | None = None) -> EgoMotion:
    """Fit the radar's own velocity to the Doppler of the stationary points of one frame.

    points: float32 (N, 5) x, y, z, doppler, snr (radar frame, m and m/s); rows with a
    non-finite value are never inliers and never moving. accuracy: the radar's accuracy
    model for the per-point thresholds (default model when None). Never raises on
    degenerate input: fewer than `min_points` points, all points along one bearing or no
    consensus give a result with a non-OK status and the reason.
    """
    cfg = config or EgoMotionConfig()
    pts = np.asarray(points)
    n = len(pts)
    finite = np.all(np.isfinite(pts[:, :4]), axis=1) if n else np.zeros(0, bool)
    idx = np.flatnonzero(finite)
    if len(idx) < cfg.min_points:
        return _no_estimate(n, EgoStatus.TOO_FEW_POINTS, f"{len(idx)} finite points < {cfg.min_points}")
    p = pts[idx]
    A = design_rows(p)
    d = p[:, DOPPLER].astype(np.float64)
    thr_all = np.zeros(n)
    thr_all[idx] = point_threshold(p, cfg)
    thr = thr_all[idx]
    spread = _bearing_spread_deg(A)
    if spread < cfg.min_bearing_spread_deg:
        return _no_estimate(n, EgoStatus.DEGENERATE_BEARING,
                            f"azimuth spread {spread:.2f} deg < {cfg.min_bearing_spread_deg}", thr_all)

    # ---- RANSAC: all 2-point hypotheses at once (draw extra, keep well-conditioned pairs)
    # the pairs are drawn from the points in a canonical order (x, y, z, Doppler): the same
    # frame listed in another order (TI lists by range, other code as it likes) gives the same fit
    m = len(p)
    rng = np.random.default_rng(cfg.seed + m)
    canon = np.lexsort((d, p[:, 2], p[:, 1], p[:, 0]))
    i = canon[rng.integers(0, m, 3 * cfg.hypotheses)]
    j = canon[rng.integers(0, m, 3 * cfg.hypotheses)]
    det = A[i, 0] * A[j, 1] - A[i, 1] * A[j, 0]       # = cos el_i cos el_j sin(az_j - az_i)
    good = np.flatnonzero(np.abs(det) > cfg.min_pair_sin)[: cfg.hypotheses]
    if len(good) == 0:
        return _no_estimate(n, EgoStatus.DEGENERATE_BEARING,
                            "no point pair is far enough apart in bearing", thr_all)
    i, j, det = i[good], j[good], det[good]
    vx = (d[i] * A[j, 1] - d[j] * A[i, 1]) / det
    vy = (A[i, 0] * d[j] - A[j, 0] * d[i]) / det
    V = np.column_stack([vx, vy])                                    # (H, 2)
    V = V[V[:, 1] >= cfg.min_forward_mps]                            # the forward-motion prior
    if len(V) == 0:
        return _no_estimate(n, EgoStatus.NO_CONSENSUS,
                            f"no hypothesis drives forward faster than {cfg.min_forward_mps} m/s", thr_all)
    R = (d[None, :] - V @ A.T) / thr[None, :]                        # (H, m) residual / threshold
    cost = np.minimum(R * R, 1.0).sum(axis=1)                        # MSAC
    v = V[int(np.argmin(cost))]

    # ---- least squares on the inliers, re-selecting them a few times
    inl = np.abs(d - A @ v) <= thr
    for _ in range(cfg.refine_iterations + 1):
        if inl.sum() < cfg.min_inliers:
            return _no_estimate(n, EgoStatus.NO_CONSENSUS,
                                f"{int(inl.sum())} stationary inliers < {cfg.min_inliers}", thr_all)
        if _bearing_spread_deg(A[inl]) < cfg.min_bearing_spread_deg:
            return _no_estimate(n, EgoStatus.DEGENERATE_BEARING,
                                "the stationary inliers lie along one bearing", thr_all)
        v = _weighted_lstsq(A[inl], d[inl], 1.0 / thr[inl] ** 2)
        new = np.abs(d - A @ v) <= thr
        if np.array_equal(new, inl):
            break
        inl = new

    if cfg.threshold_sigma > 0:
        # ---- second pass: per-point thresholds from the radar's accuracy at the fitted velocity
        thr = np.maximum(cfg.threshold_sigma * stationary_doppler_sigma(p, v, accuracy or RadarAccuracyConfig()),
                         cfg.threshold_floor_mps)
        thr_all[idx] = thr
        for _ in range(2):
            inl = np.abs(d - A @ v) <= thr
            if inl.sum() < cfg.min_inliers or _bearing_spread_deg(A[inl]) < cfg.min_bearing_spread_deg:
                break
            v = _weighted_lstsq(A[inl], d[inl], 1.0 / thr[inl] ** 2)

    if not np.linalg.norm(v) <= cfg.max_speed_mps:
        return _no_estimate(n, EgoStatus.NO_CONSENSUS,
                            f"fitted speed {np.linalg.norm(v):.1f} m/s > {cfg.max_speed_mps}", thr_all)
    if v[1] < cfg.min_forward_mps:
        return _no_estimate(n, EgoStatus.NO_CONSENSUS,
                            f"fitted forward speed {v[1]:.1f} m/s < {cfg.min_forward_mps}", thr_all)
    residual = np.zeros(n)
    residual[idx] = d - A @ v
    moving = np.zeros(n, bool)
    moving[idx] = np.abs(residual[idx]) > thr
    return EgoMotion(velocity=v.astype(np.float64), residual=residual.astype(np.float32),
                     threshold=thr_all.astype(np.float32), moving=moving, status=EgoStatus.OK,
                     reason="", inliers=int(inl.sum()))
