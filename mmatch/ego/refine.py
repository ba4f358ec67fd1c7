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

from mmatch.ego.observations import Observations, best_combination, combination_squares, modes_at, paired
from mmatch.ego.rigid import inv2


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
    bg_max_points: int = 100            # > 0: use an evenly spaced subset of the other background


def _rots(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.empty(np.shape(yaw) + (2, 2))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    return out


def _solve3(M: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solutions x of M x = b for (n, 3, 3) symmetric M, by the adjugate (np.linalg's solve and
    det cost more than this algebra on a few small systems), and which systems are solvable:
    det M > 1e-9 and M[1, 1] > 0 (x = 0 elsewhere)."""
    a, b_, c = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2]
    d, e, f = M[:, 1, 1], M[:, 1, 2], M[:, 2, 2]
    A00, A01, A02 = d * f - e * e, c * e - b_ * f, b_ * e - c * d
    A11, A12, A22 = a * f - c * c, b_ * c - a * e, a * d - b_ * b_
    det = a * A00 + b_ * A01 + c * A02
    ok = (det > 1e-9) & (d > 0)
    inv = ok / np.where(ok, det, 1.0)
    b0, b1, b2 = b[:, 0] * inv, b[:, 1] * inv, b[:, 2] * inv
    return np.column_stack([A00 * b0 + A01 * b1 + A02 * b2, A01 * b0 + A11 * b1 + A12 * b2,
                            A02 * b0 + A12 * b1 + A22 * b2]), ok


# J^T W J and J^T W r from the nine per-hypothesis sums of `_normal_equations`: (yaw, tx, ty)
_H_FROM_SUMS = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])
_H_SIGNS = np.array([1.0, -1.0, -1.0, -1.0, 1.0, 1.0, -1.0, 1.0, 1.0])
_G_SIGNS = np.array([1.0, -1.0, -1.0])
# a point p (k, 2) swapped and times this: (p_y, -p_x) = -d(R p)/dyaw for the rotated p
_FLIP = np.array([1.0, -1.0])


def _summands(dr: np.ndarray, Wd: np.ndarray, W00: np.ndarray | float, W01: np.ndarray | float,
              W11: np.ndarray | float, Wr: np.ndarray) -> np.ndarray:
    """(k, 9) what k residual terms add to the sums of `_normal_equations`: dr' W dr, W dr (2),
    W00, W01, W11, dr' W r, W r (2). dr, Wd = W dr, Wr = W r: (k, 2); the weight's entries
    (k,) or one for all."""
    X = np.empty((len(dr), 9))
    X[:, 0] = dr[:, 0] * Wd[:, 0] + dr[:, 1] * Wd[:, 1]
    X[:, 1:3] = Wd
    X[:, 3], X[:, 4], X[:, 5] = W00, W01, W11
    X[:, 6] = dr[:, 0] * Wr[:, 0] + dr[:, 1] * Wr[:, 1]
    X[:, 7:9] = Wr
    return X


def _normal_equations(n: int, h_: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations H (n, 3, 3), g (n, 3) of n hypotheses from k residual terms.

    Term i belongs to hypothesis h_[i]; its residual r has weight W (2x2 symmetric, any scale
    folded in) and Jacobian J = [dr | -I] in (yaw, tx, ty); X (k, 9) are its `_summands`.
    J^T W J = [[dr' W dr, -dr' W], [-W dr, W]] and J^T W r = [dr' W r, -W r], summed per
    hypothesis in one matrix product.
    """
    S = (h_ == np.arange(n)[:, None]) @ X
    g = S[:, 6:9] * _G_SIGNS
    return (S[:, _H_FROM_SUMS] * _H_SIGNS).reshape(n, 3, 3), g


class _VehicleTerms:
    """The matched-vehicle terms of a refinement: each hypothesis's mutually nearest vehicle
    pairs (Mahalanobis, best combination of the two views' estimates) within `gate`, among the
    pairs `usable` (Va, Vb) allows; per-call quantities computed once."""

    def __init__(self, A: Observations, B: Observations, usable: np.ndarray, gate: float) -> None:
        self.Va, self.Vb, self.gate = len(A.centres), len(B.centres), gate
        self.AB = paired(A, B)
        self.blocked = np.where(usable, 0.0, np.inf).astype(np.float32)[:, :, None]
        self.own_index = np.arange(self.Va)[:, None]
        # both estimates stacked as `best_combination`'s modes index them: best, then camera
        self.ca, self.Sa = np.concatenate([A.centres, A.cam_centres]), np.concatenate([A.cov, A.cam_cov])
        self.cb, self.Sb = np.concatenate([B.centres, B.cam_centres]), np.concatenate([B.cov, B.cam_cov])

    def terms(self, Rm: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hypothesis (k,) and `_summands` (k, 9) of the pairs of hypotheses Rm (h, 2, 2), t (h, 2)."""
        Va, Vb = self.Va, self.Vb
        q = combination_squares(self.AB, Rm, t)                              # (2 Va, 2 Vb, h)
        dm = best_combination(q, Va, Vb)
        dm += self.blocked                                                    # inf: not usable
        j = dm.argmin(axis=1)                                                 # (Va, h)
        back = dm.argmin(axis=0)                                              # (Vb, h)
        # (Va, h): the own vehicle is its nearest other vehicle's nearest, within the gate
        mutual = (back[j, np.arange(len(t))] == self.own_index) & (dm.min(axis=1) < self.gate)
        h_, a_ = np.nonzero(mutual.T)                                         # h_ ascends
        b_ = j[a_, h_]
        m_ = modes_at(q, Va, Vb, a_, b_, h_)
        ia, ib = (m_ >> 1) * Va + a_, (m_ & 1) * Vb + b_
        Rk = Rm[h_]
        rb = (Rk @ self.cb[ib][:, :, None])[..., 0]                           # R b, (k, 2)
        r = self.ca[ia] - (rb + t[h_])
        dr = rb[:, ::-1] * _FLIP                                              # -d(R b)/dyaw
        W = inv2(self.Sa[ia] + Rk @ self.Sb[ib] @ Rk.transpose(0, 2, 1))
        return h_, _summands(dr, (W @ dr[:, :, None])[..., 0], W[:, 0, 0], W[:, 0, 1], W[:, 1, 1],
                             (W @ r[:, :, None])[..., 0])


def _background_terms(tree: cKDTree, bg_other: np.ndarray, Rm: np.ndarray, t: np.ndarray, gate: float,
                      trim: float, w: float) -> tuple[np.ndarray, np.ndarray]:
    """Hypothesis (k,) and `_summands` (k, 9) of the background terms of hypotheses Rm (h, 2, 2),
    t (h, 2): the other background (N, 2) on its nearest own point within `gate` (m), the
    `trim` share of each hypothesis's nearest (with at least 3), weight w I each."""
    n = len(t)
    rot = bg_other @ Rm.transpose(0, 2, 1)                                    # R p, (h, N, 2)
    moved = rot + t[:, None]
    d, k = tree.query(moved.reshape(-1, 2), distance_upper_bound=gate)
    d, k = d.reshape(n, -1), k.reshape(n, -1)                                 # d: inf beyond the gate
    cnt = np.isfinite(d).sum(axis=1)
    cut = np.sort(d, axis=1)[np.arange(n), np.maximum(np.ceil(trim * cnt).astype(int) - 1, 0)]
    # the trimmed share of each hypothesis's correspondences (with >= 3, cut is finite)
    h_, p_ = np.nonzero((d <= cut[:, None]) & (cnt[:, None] >= 3))
    dr = rot[h_, p_][:, ::-1] * _FLIP                                         # -d(R p)/dyaw
    r = tree.data[k[h_, p_]] - moved[h_, p_]
    return h_, _summands(dr, w * dr, w, 0.0, w, w * r)


def refine(A: Observations, B: Observations, D: np.ndarray, bg_own: np.ndarray, bg_other: np.ndarray,
           R: np.ndarray, t: np.ndarray, yaws: np.ndarray | None, cfg: RefineConfig = RefineConfig(),
           tree: cKDTree | None = None, allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Refine one hypothesis (R (2, 2), t (2,)) of the other -> own transform; returns R, t.

    D: (Va, Vb) descriptor distances; bg_own / bg_other: (N, 2) background x, y (m);
    yaws: candidate yaws from the heading prior (rad) or None; allowed: (Va, Vb) pairs that
    may be used (None: all).
    """
    Rs, ts = refine_many(A, B, D, bg_own, bg_other, np.asarray(R)[None], np.asarray(t, float)[None], yaws,
                         cfg, tree, allowed)
    return Rs[0], ts[0]


def refine_many(A: Observations, B: Observations, D: np.ndarray, bg_own: np.ndarray, bg_other: np.ndarray,
                R: np.ndarray, t: np.ndarray, yaws: np.ndarray | None, cfg: RefineConfig = RefineConfig(),
                tree: cKDTree | None = None, allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`refine` for H hypotheses at once: R (H, 2, 2), t (H, 2) -> refined R, t (same shapes)."""
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0]).astype(float)
    t = np.asarray(t, float).copy()
    H_n = len(yaw)
    if H_n == 0:
        return R, t
    if tree is None and len(bg_own) >= 3:
        tree = cKDTree(bg_own)
    if allowed is not None:
        ia, ib = np.nonzero(allowed)
        if len(np.unique(ia)) == len(ia) and len(np.unique(ib)) == len(ib):
            # one-to-one pairs (an aligner's matched vehicles): only they take part
            A, B, D = A.subset(ia), B.subset(ib), D[ia][:, ib]
            allowed = np.eye(len(ia), dtype=bool)
    ok_pair = D < cfg.desc_gate if allowed is None else allowed & (D < cfg.desc_gate)
    if cfg.bg_max_points > 0 and len(bg_other) > cfg.bg_max_points:
        bg_other = bg_other[np.linspace(0, len(bg_other) - 1, cfg.bg_max_points).astype(int)]
    use_bg = tree is not None and len(bg_other) >= 3
    active = np.ones(H_n, bool)
    vehicles = _VehicleTerms(A, B, ok_pair, cfg.vehicle_gate) if len(A.centres) and len(B.centres) else None
    if use_bg:
        bg_other = np.asarray(bg_other, float)
        w = cfg.bg_weight_total / len(bg_other) / cfg.bg_sigma_m ** 2
    heading_gate, wy = np.radians(cfg.heading_gate_deg), np.radians(cfg.heading_sigma_deg) ** -2
    for it in range(cfg.iterations):
        # only the hypotheses still moving are worked on (each one's fit is its own)
        idx = np.flatnonzero(active)
        y_a, t_a, n_a = yaw[idx], t[idx], len(idx)
        Rm = _rots(y_a)                                           # (h, 2, 2)
        terms = []                                                # (hypothesis (k,), summands (k, 9))
        if vehicles is not None:
            terms.append(vehicles.terms(Rm, t_a))
        if use_bg:
            gate = cfg.bg_gate_start_m + (cfg.bg_gate_end_m - cfg.bg_gate_start_m) * it / max(cfg.iterations - 1, 1)
            terms.append(_background_terms(tree, bg_other, Rm, t_a, gate, cfg.bg_trim, w))
        if terms:
            Hm, g = _normal_equations(n_a, np.concatenate([h for h, _ in terms]),
                                      np.concatenate([x for _, x in terms]))
        else:
            Hm, g = np.zeros((n_a, 3, 3)), np.zeros((n_a, 3))
        if yaws is not None:
            gap = (y_a[:, None] - yaws + np.pi) % (2 * np.pi) - np.pi
            near = gap[np.arange(n_a), np.abs(gap).argmin(axis=1)]
            on = np.abs(near) < heading_gate
            Hm[:, 0, 0] += wy * on
            g[:, 0] += wy * near * on
        step, solvable = _solve3(Hm, -g)
        if not solvable.any():
            break
        active[idx] = solvable & (np.abs(step).max(axis=1) >= 1e-4)
        yaw[idx] = y_a + step[:, 0]
        t[idx] = t_a + step[:, 1:]
        if not active.any():
            break
    return _rots(yaw), t

