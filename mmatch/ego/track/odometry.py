"""A radar's own rotation between two of its frames, from its stationary background.

The Doppler ego-motion fit gives each radar's velocity, not its yaw rate; the tracker took the
yaw rate from the candidates that measure the relative pose and, in a turn, from the radar's
sideways velocity over an assumed lever arm (ego/track/predict.py). Where no candidate
measures a turn the track coasted on that bound: on the drives of seed 500 at 10 Hz a CAV
turning at 45 deg/s was tracked at 30 deg/s and published 14-18 deg off. The world a radar sees
standing still turns the other way by exactly the radar's rotation, so registering a frame's
background sketch (cav/background.py) to the previous frame's measures it directly.

Geometry (a radar's own frame: x right, y forward, m; angles counter-clockwise, rad): over dt
the radar moves by d = R(phi / 2) v dt (v the mean of the two frames' Doppler velocities, as
the pose filter's motion model has it, ego/track/filter.py) and turns by phi, so a stationary
point p of the previous frame appears at R(-phi) (p - d). The rotation is searched around a
guess in coarse steps on the trimmed nearest-neighbour cost, then refined by a few Gauss-Newton
steps on the correspondences within the gate (the translation follows from phi); its standard
deviation is the residuals' spread over the lever of the points' ranges, at least
`min_sigma_deg` (against the truth on the tuning drives, the difference of the two radars'
rotations spread 0.29-0.41 deg a frame pair). About 1.3 ms a frame pair for both radars; a
fine grid in place of the Gauss-Newton steps spread 0.42-0.60 deg at 1.5 ms, the coarse search
on 40 points 0.42-0.50 at 1.1 ms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class OdometryConfig:
    """search_deg / max_turn_dps / coarse_deg: the rotation searched within +-search_deg of the
    guess, or +-max_turn_dps x dt when frames are farther apart (a gap in the frames: a turn can
    begin unseen), in coarse_deg steps, then refined by `iterations` Gauss-Newton steps; gate_m: a
    correspondence farther than this counts as this far (trimmed cost); min_points: each
    background needs this many points and the best rotation this many correspondences within
    gate_m; max_points: a background of more points is thinned to about this many (every k-th:
    our CAV side sends at most 600, cav/config.py; a sender's 4096 must not cost the Ego its
    rate); min_sigma_deg: the smallest standard deviation a rotation is given."""

    search_deg: float = 9.0
    max_turn_dps: float = 60.0
    coarse_deg: float = 1.5
    iterations: int = 3
    gate_m: float = 1.0
    min_points: int = 15
    max_points: int = 600
    min_sigma_deg: float = 0.5


def displacement(v_prev: np.ndarray, v_now: np.ndarray, phi: np.ndarray, dt: float) -> np.ndarray:
    """(K, 2) the radar's displacement in the previous frame for rotations phi (K,) rad over dt s."""
    v = (np.asarray(v_prev, float) + np.asarray(v_now, float)) / 2
    c, s = np.cos(phi / 2), np.sin(phi / 2)
    return np.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]], axis=1) * dt


def _moved(prev: np.ndarray, v_prev: np.ndarray, v_now: np.ndarray, phi: np.ndarray,
           dt: float) -> tuple[np.ndarray, np.ndarray]:
    """For rotations phi (K,): the previous points less the displacement, q (K, N, 2), and where
    they appear in the new frame, R(-phi) q (K, N, 2)."""
    q = prev[None] - displacement(v_prev, v_now, phi, dt)[:, None]
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
    return q, np.stack([c * q[..., 0] + s * q[..., 1], -s * q[..., 0] + c * q[..., 1]], axis=-1)


def _thinned(points: np.ndarray, at_most: int) -> np.ndarray:
    """Every k-th of points (N, 2), k the smallest that leaves at most `at_most`."""
    return points[:: int(np.ceil(len(points) / at_most))] if len(points) > at_most else points


def rotation(prev_bg: np.ndarray, now_bg: np.ndarray, v_prev: np.ndarray, v_now: np.ndarray, dt: float,
             guess: float = 0.0, cfg: OdometryConfig = OdometryConfig()) -> tuple[float, float] | None:
    """The radar's rotation (rad, counter-clockwise) from the frame of background prev_bg (N, 2+)
    to the frame of now_bg (M, 2+), both x, y in their own radar frames (m), over dt s with
    Doppler velocities v_prev, v_now (2,) m/s; and its standard deviation (rad). None when a
    background is too sparse or too few points correspond."""
    prev, now = (_thinned(np.asarray(b, float)[:, :2], cfg.max_points) for b in (prev_bg, now_bg))
    if len(prev) < cfg.min_points or len(now) < cfg.min_points or not dt > 0:
        return None
    tree = cKDTree(now)
    span, step = np.radians(max(cfg.search_deg, cfg.max_turn_dps * dt)), np.radians(cfg.coarse_deg)
    coarse = guess + np.arange(-span, span + step / 2, step)
    _, moved = _moved(prev, v_prev, v_now, coarse, dt)
    dist, _ = tree.query(moved.reshape(-1, 2), distance_upper_bound=cfg.gate_m)
    cost = (np.minimum(dist.reshape(len(coarse), -1), cfg.gate_m) ** 2).sum(axis=1)   # trimmed
    phi = float(coarse[int(np.argmin(cost))])
    for it in range(cfg.iterations + 1):
        q, moved = (a[0] for a in _moved(prev, v_prev, v_now, np.array([phi]), dt))
        dist, idx = tree.query(moved, distance_upper_bound=cfg.gate_m)
        inlier = np.isfinite(dist)
        if inlier.sum() < cfg.min_points:
            return None
        if it == cfg.iterations:
            break
        # Gauss-Newton on the correspondences: d(R(-phi) q)/dphi
        c, s = np.cos(phi), np.sin(phi)
        qi = q[inlier]
        g = np.column_stack([-s * qi[:, 0] + c * qi[:, 1], -c * qi[:, 0] - s * qi[:, 1]])
        r = moved[inlier] - now[idx[inlier]]
        phi -= float((r * g).sum() / (g * g).sum())
    spread = float(np.sqrt(np.mean(dist[inlier] ** 2)))
    sigma = max(np.radians(cfg.min_sigma_deg), 2.0 * spread / float(np.sqrt((prev[inlier] ** 2).sum())))
    return phi, float(sigma)
