"""Which way a folder's Doppler counts: DESIGN.md's convention (positive = range increasing) or
the opposite, judged by which one the radars' ego-motion fits explain.

A radar on a vehicle driving forwards sees the stationary world approach, and the ego-motion
fit (cav/egomotion.py) explains most returns by one forward velocity of the radar: under
DESIGN.md's convention. With the sign the other way round the fit, which keeps only forward
velocities (its prior), explains few returns or none, while the same points with their Doppler
negated fit as well as a right frame does; read as they are, such frames lose their moving
vehicles and ego-velocities (on 60 wide hard scenes of seed 2 with the sign flipped: success
0.700 -> 0.083). So
each frame of a moving radar votes for the convention whose fit explains more of its returns,
and a folder whose frames nearly all vote against DESIGN.md's is read with the sign flipped
(`mmatch eval` and the commands built on it; a single scene keeps DESIGN.md's sign). The
product's radars look forwards: one mounted facing backwards would be judged the same way.
"""

from __future__ import annotations

import numpy as np

from mmatch.cav.egomotion import fit_egomotion

MIN_SPEED_MPS = 3.0          # slower radars' frames fit either sign about as well
MIN_FRAMES = 10              # moving frames the judgement needs
REVERSED_SHARE = 0.9         # share of them voting for the other sign that flips it


def sign_vote(points: np.ndarray) -> float:
    """One frame's vote on its Doppler convention from its points (N, 5): +1 when the ego-motion
    fit explains more of its returns as they are, -1 when more with their Doppler negated, NaN
    when neither fits or the radar moves slower than MIN_SPEED_MPS (both then fit alike)."""
    p = np.asarray(points, np.float32).reshape(-1, 5)
    fits = [fit_egomotion(q) for q in (p, with_sign(p, -1))]
    n = [f.inliers if f.ok and np.hypot(*f.velocity) >= MIN_SPEED_MPS else 0 for f in fits]
    if max(n) == 0 or n[0] == n[1]:
        return float("nan")
    return 1.0 if n[0] > n[1] else -1.0


def judge_sign(votes) -> int:
    """+1 (DESIGN.md's sign) or -1 from frames' `sign_vote`s (NaN entries skipped): -1 only when
    at least MIN_FRAMES voted and at least REVERSED_SHARE of them for the other sign."""
    v = np.asarray(list(votes), float)
    v = v[np.isfinite(v)]
    if len(v) < MIN_FRAMES:
        return 1
    return -1 if np.mean(v < 0) >= REVERSED_SHARE else 1


def with_sign(points: np.ndarray, sign: int) -> np.ndarray:
    """points (N, 5) with their Doppler multiplied by sign (the array itself when +1)."""
    if sign >= 0:
        return points
    out = np.array(points, np.float32, copy=True)
    out[:, 3] = -out[:, 3]
    return out
