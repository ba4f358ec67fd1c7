"""Carry T_ego_cav from frame to frame: predict it with both radars' own motion.

Between two frames each radar moves by its Doppler-fitted velocity times the time since
its previous frame (straight-line motion; yaw rates are not observed and roads are mostly
straight over a few frames). The predicted transform seeds the matcher and, when a frame
offers nothing to match (no vehicle in one view), still gives the aligner a start that the
backgrounds and the heading prior refine. A new estimate replaces the track only when it
is trusted: two or more matched vehicles, or close to the prediction.

Frames: T maps CAV-radar coordinates into Ego-radar coordinates (DESIGN.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class TrackConfig:
    max_age_s: float = 2.0          # a track older than this (own clock) is dropped; 0: no tracking
    agree_m: float = 2.0            # an estimate this close to the prediction is trusted...
    agree_deg: float = 5.0
    min_pairs: int = 2              # ...as is one with this many matched vehicles
    full_search_every: int = 10     # frames between full (global) searches while tracking
    confidence_half_life_s: float = 3.0   # a track's carried confidence halves every this long
                                          # without a frame sure of itself on its own


@dataclass
class _Track:
    T: np.ndarray
    own_stamp: float
    other_stamp: float
    since_full: int = 0
    confidence: float = float("nan")
    confident_stamp: float = float("nan")


def _shift(v: np.ndarray, dt: float) -> np.ndarray:
    """4x4 taking a radar's new coordinates to its old ones after it moved v (2,) m/s for dt s."""
    M = np.eye(4)
    M[:2, 3] = np.asarray(v, float) * dt
    return M


def _velocity(frame: SharedFrame) -> np.ndarray:
    v = np.asarray(frame.ego_velocity, float).reshape(2)
    return v if np.all(np.isfinite(v)) else np.zeros(2)


class Tracker:
    """Last trusted transform per CAV (by sender id), predicted forward on request."""

    def __init__(self, config: TrackConfig = TrackConfig()) -> None:
        self.cfg = config
        self._tracks: dict[str, _Track] = {}

    @property
    def enabled(self) -> bool:
        return self.cfg.max_age_s > 0

    def predict(self, own: SharedFrame, other: SharedFrame) -> np.ndarray | None:
        """T_ego_cav at the two frames' stamps from the sender's track, or None (no or stale track)."""
        tr = self._tracks.get(other.sender) if self.enabled else None
        if tr is None:
            return None
        dt_own, dt_other = own.stamp - tr.own_stamp, other.stamp - tr.other_stamp
        if abs(dt_own) > self.cfg.max_age_s or abs(dt_other) > self.cfg.max_age_s:
            del self._tracks[other.sender]
            return None
        # a fixed point: p_old = p_new + v dt in each radar's frame
        own_new_from_old = np.linalg.inv(_shift(_velocity(own), dt_own))
        return own_new_from_old @ tr.T @ _shift(_velocity(other), dt_other)

    def confidence(self, own: SharedFrame, other: SharedFrame) -> float:
        """What the sender's track vouches for at the own frame's stamp: the confidence of the last
        estimate that was sure on its own, halving every confidence_half_life_s since (NaN: no track)."""
        tr = self._tracks.get(other.sender)
        if tr is None or not np.isfinite(tr.confidence):
            return float("nan")
        age = max(float(own.stamp) - tr.confident_stamp, 0.0)
        return float(tr.confidence * 0.5 ** (age / max(self.cfg.confidence_half_life_s, 1e-6)))

    def agrees(self, T: np.ndarray, predicted: np.ndarray | None) -> bool:
        """Whether an estimate lies within agree_m / agree_deg of the track's prediction."""
        if predicted is None:
            return False
        d = np.linalg.norm(T[:2, 3] - predicted[:2, 3])
        yaw = np.degrees(abs((np.arctan2(T[1, 0], T[0, 0]) - np.arctan2(predicted[1, 0], predicted[0, 0])
                              + np.pi) % (2 * np.pi) - np.pi))
        return bool(d <= self.cfg.agree_m and yaw <= self.cfg.agree_deg)

    def tracking_only(self, other: SharedFrame) -> bool:
        """Whether the next frame of this sender may skip the global search."""
        tr = self._tracks.get(other.sender)
        return tr is not None and 0 < tr.since_full < self.cfg.full_search_every

    def update(self, own: SharedFrame, other: SharedFrame, T: np.ndarray | None, n_pairs: int,
               predicted: np.ndarray | None, full_search: bool = True,
               own_confidence: float = float("nan")) -> bool:
        """Keep T as the sender's track when trusted; returns whether it was kept.

        full_search: T came from a global search (else from refining the prediction alone);
        an untrusted result forces the next frame to search globally. own_confidence: how sure
        this frame's estimate is on its own; the track keeps the last one at least as sure as
        what it vouches for (see `confidence`).
        """
        if not self.enabled or T is None:
            old = self._tracks.get(other.sender)
            if old is not None:
                old.since_full = 0
            return False
        trusted = n_pairs >= self.cfg.min_pairs or self.agrees(T, predicted)
        old = self._tracks.get(other.sender)
        if trusted:
            since = 1 if full_search or old is None else old.since_full + 1
            carried = self.confidence(own, other) if old is not None else float("nan")
            if np.isfinite(own_confidence) and not own_confidence < carried:
                conf, stamp = float(own_confidence), float(own.stamp)
            else:
                conf, stamp = (old.confidence, old.confident_stamp) if old is not None else (float("nan"), float("nan"))
            self._tracks[other.sender] = _Track(np.asarray(T, float).copy(), float(own.stamp), float(other.stamp),
                                                since, conf, stamp)
        elif old is not None:
            old.since_full = 0
        return trusted

    def reset(self, sender: str | None = None) -> None:
        """Forget one sender's track, or all."""
        if sender is None:
            self._tracks.clear()
        else:
            self._tracks.pop(sender, None)
