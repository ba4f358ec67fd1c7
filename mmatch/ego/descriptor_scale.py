"""Calibrating appearance-descriptor distances to the cameras at hand.

The matchers' appearance gates and likelihoods are set in Hellinger distance for cameras
where two *different* vehicles are typically 0.39 apart (the median over a frame pair's
Ego x CAV descriptor pairs, most of which are different vehicles). Cameras that agree less
(another white balance, blur, a learned embedding of another scale) push true pairs and
different vehicles apart alike; cameras that agree more pull them together. Without a
correction the first make every true pair look unlike, the second every vehicle alike.

One frame pair's median swings with its content (0.28-0.48 across simulated scenes: a
street of white cars looks alike), so the scale comes from many frame pairs: a running
median in the vehicle service, a folder's median in `mmatch eval`. It never uses labels.
Even that moves with the mix of scenes (a folder of easy roads with few, distinct vehicles
sits 5 % lower than one of crowded junctions), so only the part of the scale beyond
CONTENT_BAND is applied.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

from mmatch.ego.base import descriptor_distance

TYPICAL_MEDIAN = 0.39       # median Ego x CAV descriptor distance of a frame pair, calibrated cameras
MIN_PAIRS = 6               # frame pairs with fewer descriptor pairs say little about the scale
MIN_FRAMES = 10             # frame pairs needed before the running scale departs from 1
SCALE_LIMITS = (0.33, 3.0)  # a scale outside these would mean the descriptors are broken, not miscalibrated
CONTENT_BAND = 1.1          # folders of calibrated cameras differ by this factor with their scene mix


def frame_median(own_features: np.ndarray, other_features: np.ndarray) -> float | None:
    """Median descriptor distance over a frame pair's Ego x CAV vehicles, or None if too few."""
    if len(own_features) * len(other_features) < MIN_PAIRS:
        return None
    return float(np.median(descriptor_distance(own_features, other_features)))


def scale_from_medians(medians: Iterable[float | None], min_frames: int = 1) -> float:
    """Factor on descriptor distances that brings the median of per-frame medians to TYPICAL_MEDIAN
    (to within CONTENT_BAND; 1 when it is already within)."""
    m = [x for x in medians if x is not None]
    if len(m) < min_frames or not m:
        return 1.0
    med = float(np.median(m))
    if med <= 0:
        return 1.0
    raw = TYPICAL_MEDIAN / med
    scale = raw / CONTENT_BAND if raw > CONTENT_BAND else raw * CONTENT_BAND if raw * CONTENT_BAND < 1 else 1.0
    return float(np.clip(scale, *SCALE_LIMITS))


def scaled_distance(own_features: np.ndarray, other_features: np.ndarray, scale: float) -> np.ndarray:
    """(Va, Vb) descriptor distances times `scale`, clipped to 0-1."""
    D = descriptor_distance(own_features, other_features)
    return D if scale == 1.0 else np.clip(D * scale, 0.0, 1.0)


class RunningDescriptorScale:
    """The scale from the last `window` frame pairs (the vehicle service's calibration)."""

    def __init__(self, window: int = 200, min_frames: int = MIN_FRAMES) -> None:
        self._medians: deque[float] = deque(maxlen=window)
        self.min_frames = min_frames

    def update(self, own_features: np.ndarray, other_features: np.ndarray) -> float:
        """Take in one frame pair's descriptors (N, 32) and return the current scale."""
        m = frame_median(own_features, other_features)
        if m is not None:
            self._medians.append(m)
        return scale_from_medians(self._medians, self.min_frames)
