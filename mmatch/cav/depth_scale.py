"""Calibrating a camera's monocular depth to the radar, from many frames and no labels.

A monocular 3D detector of another make, lens or training set can misjudge every depth by
the same factor. The CAV side reads each radar return's range against its box's depth, so a
bias of 15 % (depth x 0.85) cost 4.8 points of pair F1 and 9.5 of success on 200 wide hard
scenes (`mmatch transfer`), more than any other shift we measured.

The radar measures range to within centimetres, so the returns of a vehicle say what its box
depth should be: per box, the log of the median range of the moving returns in the box's
columns (within 0.5-2 times its depth, from the camera) over the box depth. Returns come from
the faces turned to the radar, not the centre the depth means, and the vehicles' mix moves
that ratio: on our simulator the folder median sits at TYPICAL_LOG_RATIO, between -0.040
(stress physics) and -0.085 (nominal easy roads). One frame's median is about as noisy
(0.085 in log) as the bias it should find, and correcting per frame cost 1.5-2.5 points of
success on unbiased scenes; a folder (`mmatch eval`) or the service's last frames give it
to within 0.01. Only the part beyond CONTENT_BAND is corrected, so every folder of our own
physics keeps its depths as they are.

Frames: radar frame (x right, y forward, z up); the camera model maps it to pixels.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

from mmatch.cav.frustum import Projection
from mmatch.numeric import median

TYPICAL_LOG_RATIO = -0.062    # folder median of box log ratios, calibrated depths (wide / nominal sims)
CONTENT_BAND = 0.03           # log units: folders of calibrated cameras lie within this of it
MIN_BOXES = 100               # boxes with returns before a scale departs from 1 (independent scenes)
RUNNING_MIN_BOXES = 300       # the same over consecutive frames, which see the same vehicles again
SCALE_LIMITS = (0.5, 2.0)     # beyond these the depths are broken, not miscalibrated
MIN_RETURNS = 2               # moving returns a box needs to give a ratio
WINDOW = (0.5, 2.0)           # returns counted between these multiples of the box depth


def box_log_ratios(boxes: np.ndarray, proj: Projection | None, moving: np.ndarray) -> np.ndarray:
    """Per box with at least MIN_RETURNS moving returns in its columns (within WINDOW times its
    depth): log(median return range from the camera / box depth). boxes: (M, 6) u1, v1, u2, v2
    (px), score, depth (m) as detected (not rescaled); proj: the frame's points in the image
    (None: no points); moving: bool (N,) from the ego-motion fit. Returns float64 (K,), K <= M."""
    boxes = np.asarray(boxes, np.float64)
    if proj is None or not len(boxes) or not moving.any():
        return np.zeros(0)
    sel = proj.front & moving
    u, rng = proj.uv[sel, 0], proj.bev_range[sel]
    depth = boxes[:, 5, None]
    inside = (u >= boxes[:, 0, None]) & (u <= boxes[:, 2, None]) \
        & (rng > WINDOW[0] * depth) & (rng < WINDOW[1] * depth)                      # (M, n)
    out = [np.log(median(rng[row]) / d) for row, d in zip(inside, depth[:, 0]) if row.sum() >= MIN_RETURNS]
    ratios = np.array(out, np.float64)
    return ratios[np.isfinite(ratios)]


def scale_from_ratios(ratios: Iterable[float], min_boxes: int = MIN_BOXES) -> float:
    """Factor on box depths that brings the median log ratio to TYPICAL_LOG_RATIO, less
    CONTENT_BAND (1 when within it, or with fewer than min_boxes ratios)."""
    r = np.fromiter(ratios, float)
    if len(r) < max(min_boxes, 1):
        return 1.0
    off = float(np.median(r)) - TYPICAL_LOG_RATIO
    excess = np.sign(off) * max(abs(off) - CONTENT_BAND, 0.0)
    return float(np.clip(np.exp(excess), *SCALE_LIMITS))


class RunningDepthScale:
    """The scale from the boxes of the last frames (the vehicle service's calibration)."""

    def __init__(self, window: int = 3000, min_boxes: int = RUNNING_MIN_BOXES) -> None:
        self._ratios: deque[float] = deque(maxlen=window)
        self.min_boxes = min_boxes
        self.scale = 1.0

    def update(self, ratios: np.ndarray) -> float:
        """Take in one frame's box log ratios (`box_log_ratios`) and return the current scale."""
        self._ratios.extend(float(x) for x in np.asarray(ratios, float).ravel() if np.isfinite(x))
        self.scale = scale_from_ratios(self._ratios, self.min_boxes)
        return self.scale
