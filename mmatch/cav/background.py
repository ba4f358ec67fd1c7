"""Stationary-background sketch: drop isolated points, then a capped voxel grid.

DBSCAN over (x, y) removes clutter and multipath ghosts, which are isolated; the survivors
are averaged per voxel and, when there are more voxels than `max_points`, the voxels with
the most returns are kept (well-supported structure first, ties by nearer range).
"""

from __future__ import annotations

import numpy as np

from mmatch.cav.config import BackgroundConfig
from mmatch.cav.dbscan import dbscan_labels


def denoise(xy: np.ndarray, config: BackgroundConfig | None = None) -> np.ndarray:
    """bool (N,): True for points in a DBSCAN cluster over (x, y) (not isolated)."""
    cfg = config or BackgroundConfig()
    if len(xy) == 0:
        return np.zeros(0, bool)
    labels = dbscan_labels(xy, cfg.eps_m, cfg.min_samples)
    return labels >= 0


def voxel_sketch(xyz: np.ndarray, config: BackgroundConfig | None = None) -> np.ndarray:
    """float32 (B, 3): mean point of each occupied voxel, at most `max_points` voxels."""
    cfg = config or BackgroundConfig()
    if len(xyz) == 0:
        return np.zeros((0, 3), np.float32)
    p = np.asarray(xyz, np.float64)
    keys = np.floor(p / cfg.voxel_m).astype(np.int64)
    _, inv, count = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    sums = np.zeros((len(count), 3))
    np.add.at(sums, inv, p)
    means = sums / count[:, None]
    if len(means) > cfg.max_points:
        rng_xy = np.hypot(means[:, 0], means[:, 1])
        order = np.lexsort((rng_xy, -count))
        means = means[np.sort(order[: cfg.max_points])]
    return means.astype(np.float32)


def sketch(xyz: np.ndarray, config: BackgroundConfig | None = None) -> np.ndarray:
    """The background sketch (B, 3) float32 of stationary points (N, 3), radar frame, m."""
    cfg = config or BackgroundConfig()
    xyz = np.asarray(xyz).reshape(-1, 3)
    keep = denoise(xyz[:, :2], cfg)
    return voxel_sketch(xyz[keep], cfg)
