"""Gauss-Newton refinement of a planar transform on vehicles, background and heading prior.

One least-squares problem over (yaw, tx, ty) of the other -> own transform:
- matched vehicles, each weighted by the inverse of its two views' summed covariance
  (see observations.py), so a pair constrains mainly across the lines of sight;
- the other view's background points on their nearest own background point within a
  gate that shrinks over the iterations (trimmed point-to-point ICP terms);
- the velocity-heading prior on the yaw, when one is near.
Vehicle pairs are re-chosen every iteration (mutual nearest in Mahalanobis distance,
alike enough), so a rough hypothesis pulls in the vehicles it explains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from mmatch.ego.observations import Observations, mahalanobis


@dataclass(frozen=True)
class RefineConfig:
    iterations: int = 6
    vehicle_gate: float = 3.0           # Mahalanobis distance of a usable vehicle pair
    desc_gate: float = 0.55
    bg_gate_start_m: float = 2.0
    bg_gate_end_m: float = 0.8
    bg_sigma_m: float = 0.7             # a background correspondence's standard deviation
    bg_weight_total: float = 4.0        # all background terms together weigh this many vehicles
    bg_trim: float = 0.8
    heading_sigma_deg: float = 3.0
    heading_gate_deg: float = 10.0


def _rot(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s], [s, c]])


def refine(A: Observations, B: Observations, D: np.ndarray, bg_own: np.ndarray, bg_other: np.ndarray,
           R: np.ndarray, t: np.ndarray, yaws: np.ndarray | None, cfg: RefineConfig = RefineConfig(),
           tree: cKDTree | None = None, allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Refine one hypothesis (R (2, 2), t (2,)) of the other -> own transform; returns R, t.

    D: (Va, Vb) descriptor distances; bg_own / bg_other: (N, 2) background x, y (m);
    yaws: candidate yaws from the heading prior (rad) or None; allowed: (Va, Vb) pairs that
    may be used (None: all).
    """
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    t = np.asarray(t, float).copy()
    if tree is None and len(bg_own) >= 3:
        tree = cKDTree(bg_own)
    ok_pair = D < cfg.desc_gate if allowed is None else allowed & (D < cfg.desc_gate)
    for it in range(cfg.iterations):
        Rm = _rot(yaw)
        H = np.zeros((3, 3))
        g = np.zeros(3)
        # vehicles: mutual nearest pairs under the current transform
        if len(A.centres) and len(B.centres):
            dm, mode = mahalanobis(A, B, Rm[None], t[None], with_modes=True)
            dm, mode = np.where(ok_pair, dm[0], np.inf), mode[0]
            i = np.arange(len(A.centres))
            j = dm.argmin(axis=1)
            mutual = (dm.argmin(axis=0)[j] == i) & (dm[i, j] < cfg.vehicle_gate)
            ma, mb = A.modes(), B.modes()
            for a, b in zip(i[mutual], j[mutual]):
                (ca, Sa, _), (cb, Sb, _) = ma[mode[a, b] // 2], mb[mode[a, b] % 2]
                pb = cb[b]
                r = ca[a] - (Rm @ pb + t)
                J = np.column_stack([-(Rm @ np.array([-pb[1], pb[0]])), -np.eye(2)])   # (2, 3)
                W = np.linalg.inv(Sa[a] + Rm @ Sb[b] @ Rm.T)
                H += J.T @ W @ J
                g += J.T @ W @ r
        # background: trimmed nearest neighbours within a shrinking gate
        if tree is not None and len(bg_other) >= 3:
            gate = cfg.bg_gate_start_m + (cfg.bg_gate_end_m - cfg.bg_gate_start_m) * it / max(cfg.iterations - 1, 1)
            moved = bg_other @ Rm.T + t
            d, k = tree.query(moved, distance_upper_bound=gate)
            ok = np.isfinite(d)
            if ok.sum() >= 3:
                ok &= d <= np.quantile(d[ok], cfg.bg_trim)
                src, r = bg_other[ok], tree.data[k[ok]] - moved[ok]
                w = cfg.bg_weight_total / max(len(bg_other), 1) / cfg.bg_sigma_m ** 2
                perp = -(np.column_stack([-src[:, 1], src[:, 0]]) @ Rm.T)               # d r / d yaw
                Jt = np.column_stack([perp[:, 0], -np.ones(len(src)), np.zeros(len(src))])
                Jy = np.column_stack([perp[:, 1], np.zeros(len(src)), -np.ones(len(src))])
                H += w * (Jt.T @ Jt + Jy.T @ Jy)
                g += w * (Jt.T @ r[:, 0] + Jy.T @ r[:, 1])
        if yaws is not None:
            gap = (yaw - yaws + np.pi) % (2 * np.pi) - np.pi
            k = int(np.argmin(np.abs(gap)))
            if abs(gap[k]) < np.radians(cfg.heading_gate_deg):
                wy = np.radians(cfg.heading_sigma_deg) ** -2
                H[0, 0] += wy
                g[0] += wy * (-gap[k]) * -1.0
        if H[1, 1] <= 0 or np.linalg.matrix_rank(H) < 3:
            break
        step = np.linalg.solve(H, -g)
        yaw += step[0]
        t = t + step[1:]
        if np.abs(step).max() < 1e-4:
            break
    return _rot(yaw), t
