"""Which camera detections the radar contradicts: boxes not to share as vehicles.

A camera detector's false detections are of three kinds (a second box on part of a real
vehicle, a box on roadside structure, a box on nothing); the radar can tell two of them:
- a duplicate: a box lying mostly inside a better-scored box at the same depth is a
  second detection of that vehicle (occluded vehicles behind a nearer one lie inside its
  box too, but much deeper);
- a see-through: a box with no radar return near its depth while the radar sees past it
  in that direction (returns beyond the box's depth, inside its columns). A real vehicle
  would hide what lies behind it; a vehicle without returns that hides nothing is not
  contradicted and stays.
Frames: pixels for boxes, metres for depths and ranges (BEV, from the camera centre).
"""

from __future__ import annotations

import numpy as np

from mmatch.cav.config import PlausibilityConfig
from mmatch.cav.frustum import Projection


def duplicates(boxes: np.ndarray, config: PlausibilityConfig = PlausibilityConfig()) -> np.ndarray:
    """bool (M,): boxes (M, 6) that are second detections of a better-scored box at the same depth."""
    m = len(boxes)
    out = np.zeros(m, bool)
    if m < 2 or not config.enabled:
        return out
    b = np.asarray(boxes, np.float64)
    area = np.maximum((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]), 1e-6)
    iw = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1]), 0, None)
    inside = iw * ih / area[:, None]                                   # (i, j): share of box i inside box j
    depth_ok = np.abs(b[:, None, 5] - b[None, :, 5]) <= config.duplicate_depth_m \
        + config.duplicate_depth_rel * np.maximum(b[:, None, 5], b[None, :, 5])
    better = (b[None, :, 4] > b[:, None, 4]) | ((b[None, :, 4] == b[:, None, 4]) & (area[None, :] > area[:, None]))
    hit = (inside >= config.containment) & depth_ok & better
    np.fill_diagonal(hit, False)
    return hit.any(axis=1)


def see_through(proj: Projection, boxes: np.ndarray, claimed: np.ndarray,
                config: PlausibilityConfig = PlausibilityConfig()) -> np.ndarray:
    """bool (M,): boxes without claimed points (claimed (M,) counts) through which the radar sees.

    proj: the frame's points projected into the camera (see frustum.project).
    """
    m = len(boxes)
    out = np.zeros(m, bool)
    if m == 0 or not config.enabled or len(proj.uv) == 0:
        return out
    b = np.asarray(boxes, np.float64)
    u = proj.uv[:, 0:1]
    with np.errstate(invalid="ignore"):
        cols = proj.front[:, None] & (u >= b[None, :, 0]) & (u <= b[None, :, 2])
    beyond = proj.bev_range[:, None] > b[None, :, 5] * (1 + config.see_through_margin_rel) \
        + config.see_through_margin_m
    n_beyond = (cols & beyond).sum(axis=0)
    return (claimed == 0) & (n_beyond >= config.see_through_points) & (b[:, 5] <= config.see_through_max_m)
