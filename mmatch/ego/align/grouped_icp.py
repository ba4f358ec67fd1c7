"""Weighted point-to-point ICP on the road plane with correspondences kept inside groups.

The ablation aligners (icp_ablation.py) and the paper's two-stage alignment (paper.py)
are all point-to-point ICP; they differ in which points take part, which points may pair
(any point with any, or a matched vehicle's points only with its partner's) and how each
correspondence is weighted. One `PointSet` says that for one kind of points; `grouped_icp`
fits one rigid SE(2) transform to several at once.

Frames: src points in the other (CAV) radar frame, dst points in the own (Ego) radar frame,
x, y in metres; the result maps src into dst: dst ~ R @ src + t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from mmatch.ego.rigid import kabsch2d

GROUP_GAP_M = 1.0e6      # groups are stacked this far apart in a third dimension of the KD tree


@dataclass
class PointSet:
    """One kind of correspondence: src (N, 2) may pair only with dst (M, 2) of the same group.

    src_group (N,), dst_group (M,): int group of each point (one group: all may pair).
    weight (N,): weight of each src point's correspondence.
    max_dist / min_dist: the correspondence gate (m), shrinking from max to min over the
        first 60 % of the iterations; trim: the share of the closest pairs kept each round.
    """

    src: np.ndarray
    dst: np.ndarray
    src_group: np.ndarray
    dst_group: np.ndarray
    weight: np.ndarray
    max_dist: float
    min_dist: float
    trim: float = 1.0

    @classmethod
    def ungrouped(cls, src: np.ndarray, dst: np.ndarray, max_dist: float, min_dist: float,
                  trim: float = 1.0, weight: float = 1.0) -> PointSet:
        """Any src point may pair with any dst point; every correspondence weighs `weight`."""
        src = np.asarray(src, np.float64).reshape(-1, 2)
        dst = np.asarray(dst, np.float64).reshape(-1, 2)
        return cls(src, dst, np.zeros(len(src), int), np.zeros(len(dst), int),
                   np.full(len(src), float(weight)), max_dist, min_dist, trim)


def _lift(xy: np.ndarray, group: np.ndarray) -> np.ndarray:
    return np.column_stack([xy, np.asarray(group, np.float64) * GROUP_GAP_M])


def grouped_icp(sets: list[PointSet], R: np.ndarray, t: np.ndarray, iterations: int = 30
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted ICP of every set's src onto its dst from (R (2, 2), t (2,)).

    Each round: nearest neighbour inside the group within the set's gate, the set's trim,
    then one weighted Kabsch over the correspondences of all sets. Returns R, t and the
    share of src points (all sets) that had a correspondence in the last round.
    """
    sets = [s for s in sets if len(s.src) and len(s.dst)]
    trees = [cKDTree(_lift(s.dst, s.dst_group)) for s in sets]
    lifted = [_lift(np.zeros_like(s.src), s.src_group) for s in sets]
    total = sum(len(s.src) for s in sets)
    inlier = 0.0
    for it in range(iterations):
        frac = min(it / max(iterations * 0.6, 1), 1.0)
        S, Q, W = [], [], []
        for s, tree, q in zip(sets, trees, lifted):
            gate = s.max_dist + (s.min_dist - s.max_dist) * frac
            q[:, :2] = s.src @ R.T + t
            d, j = tree.query(q, distance_upper_bound=gate)
            ok = np.isfinite(d)
            if s.trim < 1.0 and ok.sum() > 3:
                ok &= d <= np.quantile(d[ok], s.trim)
            S.append(s.src[ok])
            Q.append(s.dst[j[ok]])
            W.append(s.weight[ok])
        src, dst, w = (np.concatenate(S), np.concatenate(Q), np.concatenate(W)) if S else \
            (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        if len(src) < 3 or w.sum() <= 0:
            break
        inlier = len(src) / total
        R_new, t_new = kabsch2d(src, dst, w)
        done = np.allclose(R_new, R, atol=1e-7) and np.allclose(t_new, t, atol=1e-5)
        R, t = R_new, t_new
        if done:
            break
    return R, t, inlier
