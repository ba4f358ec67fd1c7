"""Planar rigid geometry on the road plane: Kabsch in 2-D, point-to-point ICP, SE(2) <-> 4x4.

Both radars sit level above a flat road, so the CAV -> Ego transform is a yaw and an
x, y translation; z is the difference of the two mounting heights, which each vehicle
knows and shares.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mmatch.numeric import lengths


def se2_to_matrix(R2: np.ndarray, t2: np.ndarray, dz: float = 0.0) -> np.ndarray:
    """4x4 float64 from a 2x2 rotation, a 2-vector translation and a z offset (m)."""
    T = np.eye(4)
    T[:2, :2] = R2
    T[:2, 3] = t2
    T[2, 3] = dz
    return T


def apply2(R2: np.ndarray, t2: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Transform (N, 2) points."""
    return pts @ R2.T + t2


def kabsch2d(src: np.ndarray, dst: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares R, t with dst ~ R @ src + t for (N, 2) point sets (N >= 2; N = 1 gives R = I)."""
    if w is None:
        w = np.ones(len(src))
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    if len(src) < 2:
        return np.eye(2), cd - cs
    H = (src - cs).T @ ((dst - cd) * w[:, None])
    ang = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    c, s = np.cos(ang), np.sin(ang)
    R = np.array([[c, -s], [s, c]])
    return R, cd - R @ cs


def icp2d(src: np.ndarray, dst: np.ndarray, R: np.ndarray, t: np.ndarray, max_dist: float = 1.5,
          min_dist: float = 0.5, iterations: int = 30, anchors: tuple[np.ndarray, np.ndarray] | None = None,
          anchor_weight: float = 0.0, trim: float = 0.8, fix_rotation: bool = False
          ) -> tuple[np.ndarray, np.ndarray, float]:
    """Point-to-point ICP of src (N, 2) onto dst (M, 2) from (R, t).

    The correspondence gate shrinks from max_dist to min_dist (m); the worst (1 - trim)
    share of pairs is dropped each round. anchors = (src_a, dst_a) are fixed
    correspondences (matched vehicles) added with anchor_weight each, which keeps the
    solution from sliding along a symmetric road. fix_rotation keeps R and fits t only.
    Returns R, t and the inlier share.
    """
    if len(src) == 0 or len(dst) == 0:
        return R, t, 0.0
    tree = cKDTree(dst)
    inlier = 0.0
    for it in range(iterations):
        gate = max_dist + (min_dist - max_dist) * min(it / max(iterations * 0.6, 1), 1.0)
        moved = apply2(R, t, src)
        d, j = tree.query(moved, distance_upper_bound=gate)
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        if trim < 1.0:
            cut = np.quantile(d[ok], trim)
            ok &= d <= cut
        inlier = float(ok.mean())
        s, q = src[ok], dst[j[ok]]
        w = np.ones(len(s))
        if anchors is not None and anchor_weight > 0 and len(anchors[0]):
            s = np.vstack([s, anchors[0]])
            q = np.vstack([q, anchors[1]])
            w = np.concatenate([w, np.full(len(anchors[0]), anchor_weight)])
        if fix_rotation:
            R_new, t_new = R, (w / w.sum()) @ (q - s @ R.T)
        else:
            R_new, t_new = kabsch2d(s, q, w)
        if np.allclose(R_new, R, atol=1e-7) and np.allclose(t_new, t, atol=1e-5):
            R, t = R_new, t_new
            break
        R, t = R_new, t_new
    return R, t, inlier


def inv2(S: np.ndarray) -> np.ndarray:
    """Inverses of (..., 2, 2) matrices, explicitly (np.linalg.inv costs more on small batches)."""
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    out = np.empty_like(S)
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = d / det, -b / det, -c / det, a / det
    return out


def rot2(yaw: np.ndarray) -> np.ndarray:
    """(..., 2, 2) rotations by yaw (..., rad, counter-clockwise)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def yaw_of(T: np.ndarray) -> float:
    """Yaw (rad) of a 4x4 or 2x2 rotation."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


def near_transforms(yaw_a: np.ndarray, t_a: np.ndarray, yaw_b: np.ndarray, t_b: np.ndarray, distinct_m: float,
                    distinct_deg: float) -> np.ndarray:
    """(A, B) whether planar transforms a (yaw (A,) rad, t (A, 2) m) and b lie within distinct_m
    and distinct_deg of each other."""
    dy = np.abs((yaw_a[:, None] - yaw_b[None] + np.pi) % (2 * np.pi) - np.pi)
    return (lengths(t_a[:, None] - t_b[None]) < distinct_m) & (dy < np.radians(distinct_deg))


def distinct_best(R: np.ndarray, t: np.ndarray, order: np.ndarray, n: int, distinct_m: float,
                  distinct_deg: float) -> np.ndarray:
    """Indices of up to n planar transforms R (H, 2, 2), t (H, 2), taken in `order` (best first),
    skipping any within distinct_m (m) and distinct_deg (deg) of one already taken.

    Blocks of `order` at a time (16, 32, 64, ...): those near one already taken drop out at
    once (in dense traffic hundreds of hypotheses agree on the best transform), and the rest
    are taken greedily on their block's pairwise nearness."""
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    order = np.asarray(order, int)

    def near(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return near_transforms(yaw[i], t[i], yaw[j], t[j], distinct_m, distinct_deg)

    chosen: list[int] = []
    lo, block = 0, 16
    while lo < len(order) and len(chosen) < n:
        blk = order[lo:lo + block]
        lo, block = lo + block, 2 * block
        if chosen:
            blk = blk[~near(blk, np.asarray(chosen)).any(axis=1)]
        close = near(blk, blk).tolist()
        local: list[int] = []
        for k in range(len(blk)):
            if len(chosen) >= n:
                break
            if not any(close[k][m] for m in local):
                local.append(k)
                chosen.append(int(blk[k]))
    return np.asarray(chosen, int)
