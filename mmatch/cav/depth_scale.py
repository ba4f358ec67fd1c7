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

Some monocular 3D detectors give the depth along the camera's optical axis rather than to the
vehicle: short by cos(bearing). Then the box log ratio rises with -log cos(bearing) at a slope
of about 1 (Theil-Sen: 1.06 / 1.12 on 1300 boxes of seeds 5 / 20, both cameras) where our
depths give 0.12 / 0.19 (one camera's 200 scenes alone: -0.64 to 0.81 over 23 folders, so a
folder judges both cameras together); past AXIS_SLOPE, over at least AXIS_MIN_BOXES boxes,
the depths are taken as along the axis and divided by cos(bearing) before the scale is
measured (`DepthCalibration`).

Frames: radar frame (x right, y forward, z up); the camera model maps it to pixels.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

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
AXIS_MIN_BOXES = 1000         # boxes before the depth convention is judged
AXIS_SLOPE = 0.7              # slope of the log ratio on -log cos(bearing) past which depths run along the axis


def box_depth_evidence(boxes: np.ndarray, proj: Projection | None, moving: np.ndarray,
                       K: np.ndarray) -> np.ndarray:
    """Per box with at least MIN_RETURNS moving returns in its columns (within WINDOW times its
    depth): log(median return range from the camera / box depth) and -log cos(bearing of the
    box centre from the optical axis). boxes: (M, 6) u1, v1, u2, v2 (px), score, depth (m) as
    detected (not rescaled); proj: the frame's points in the image (None: no points); moving:
    bool (N,) from the ego-motion fit; K: (3, 3) intrinsics. Returns float64 (B, 2), B <= M."""
    boxes = np.asarray(boxes, np.float64)
    if proj is None or not len(boxes) or not moving.any():
        return np.zeros((0, 2))
    sel = proj.front & moving
    u, rng = proj.uv[sel, 0], proj.bev_range[sel]
    depth = boxes[:, 5, None]
    inside = (u >= boxes[:, 0, None]) & (u <= boxes[:, 2, None]) \
        & (rng > WINDOW[0] * depth) & (rng < WINDOW[1] * depth)                      # (M, n)
    K = np.asarray(K, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = -np.log(np.cos(box_bearings(boxes, K)))
        out = [(np.log(median(rng[row]) / d), a) for row, d, a in zip(inside, depth[:, 0], axis)
               if row.sum() >= MIN_RETURNS]
    ev = np.array(out, np.float64).reshape(-1, 2)
    return ev[np.isfinite(ev).all(axis=1)]


def box_bearings(boxes: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(M,) horizontal angle of each box centre from the optical axis, rad."""
    return np.arctan(((boxes[:, 0] + boxes[:, 2]) / 2 - K[0, 2]) / K[0, 0])


def axis_slope(evidence: np.ndarray, pairs: int = 20000) -> float | None:
    """How the log ratio rises with -log cos(bearing): the Theil-Sen slope (the median of the
    slopes between `pairs` pairs of boxes drawn with a fixed seed, pairs whose axis terms
    differ by at least 0.01); None with fewer than 8 boxes or too few such pairs."""
    ev = np.asarray(evidence, float).reshape(-1, 2)
    if len(ev) < 8:
        return None
    i, j = np.random.default_rng(0).integers(0, len(ev), (2, pairs))
    dx = ev[i, 1] - ev[j, 1]
    ok = np.abs(dx) > 0.01
    if ok.sum() < 100:
        return None
    return float(np.median((ev[i, 0] - ev[j, 0])[ok] / dx[ok]))


@dataclass(frozen=True)
class DepthCalibration:
    """A camera's depth calibration: depths along the optical axis turned into distances
    (divided by cos(bearing)), then times scale."""

    scale: float = 1.0
    along_axis: bool = False

    def apply(self, boxes: np.ndarray, K: np.ndarray) -> np.ndarray:
        """The boxes (M, 6) with calibrated depths (a copy; the same array when nothing changes)."""
        if self.scale == 1.0 and not self.along_axis:
            return boxes
        out = np.array(boxes, copy=True)
        factor = np.full(len(out), self.scale)
        if self.along_axis and len(out):
            with np.errstate(invalid="ignore"):
                factor = factor / np.cos(box_bearings(np.asarray(out, np.float64), np.asarray(K, np.float64)))
        out[:, 5] = out[:, 5] * factor
        return out


def along_axis(evidence: np.ndarray) -> bool:
    """Whether `box_depth_evidence` rows (B, 2) say the depths run along the optical axis."""
    ev = np.asarray(evidence, float).reshape(-1, 2)
    slope = axis_slope(ev) if len(ev) >= AXIS_MIN_BOXES else None
    return slope is not None and slope > AXIS_SLOPE


def calibrate(evidence: np.ndarray, min_boxes: int = MIN_BOXES, along: bool | None = None) -> DepthCalibration:
    """The calibration `box_depth_evidence` rows (B, 2) call for (1 and range depths with too
    few); along: the depth convention when judged on more evidence (None: from these rows)."""
    ev = np.asarray(evidence, float).reshape(-1, 2)
    along = along_axis(ev) if along is None else along
    ratios = ev[:, 0] - ev[:, 1] if along else ev[:, 0]
    return DepthCalibration(scale_from_ratios(ratios, min_boxes), along)


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
    """The calibration from the boxes of the last `window` (the vehicle service's). One camera's
    boxes say less about the depth convention than a folder's two cameras: it is judged only on
    a full window, every `judge_every` frames, and once taken as along the axis it is given up
    only below AXIS_SLOPE - 0.3 (no flicker at the boundary)."""

    def __init__(self, window: int = 3000, min_boxes: int = RUNNING_MIN_BOXES, judge_every: int = 200) -> None:
        self._evidence = np.zeros((window, 2))        # a ring of the latest rows
        self._count = 0
        self._frames = 0
        self.min_boxes = min_boxes
        self.judge_every = judge_every
        self.calibration = DepthCalibration()

    @property
    def scale(self) -> float:
        return self.calibration.scale

    def update(self, evidence: np.ndarray) -> DepthCalibration:
        """Take in one frame's `box_depth_evidence` (B, 2) and return the current calibration."""
        ev = np.asarray(evidence, float).reshape(-1, 2)
        ev = ev[np.isfinite(ev).all(axis=1)][-len(self._evidence):]
        self._frames += 1
        if not len(ev):
            return self.calibration
        rows = (self._count + np.arange(len(ev))) % len(self._evidence)
        self._evidence[rows] = ev
        self._count += len(ev)
        held = self._evidence[:min(self._count, len(self._evidence))]
        along = self.calibration.along_axis
        if self._count >= len(self._evidence) and self._frames % self.judge_every == 0:
            slope = axis_slope(held)
            if slope is not None:
                along = slope > (AXIS_SLOPE - 0.3 if along else AXIS_SLOPE)
        self.calibration = calibrate(held, self.min_boxes, along=along)
        return self.calibration
