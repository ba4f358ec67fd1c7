"""Planar rigid helpers: distinct best hypotheses."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.rigid import distinct_best


def _greedy(R, t, order, n, distinct_m, distinct_deg):
    """The definition: walk the order, keep a hypothesis unless one kept is within both gates."""
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    kept = []
    for h in order:
        if len(kept) == n:
            break
        near = [np.hypot(*(t[h] - t[k])) < distinct_m
                and abs((yaw[h] - yaw[k] + np.pi) % (2 * np.pi) - np.pi) < np.radians(distinct_deg) for k in kept]
        if not any(near):
            kept.append(int(h))
    return kept


@pytest.mark.parametrize("spread_m, spread_rad", [(2.0, 0.02), (20.0, 0.3), (0.5, 0.01)])
@pytest.mark.parametrize("H", [0, 1, 7, 40, 700])
def test_distinct_best_is_the_greedy_walk_down_the_order(H, spread_m, spread_rad):
    rng = np.random.default_rng(H)
    yaw = rng.normal(0, spread_rad, H) + np.where(rng.random(H) < 0.2, np.pi, 0.0)   # some flipped
    R = np.stack([np.stack([np.cos(yaw), -np.sin(yaw)], -1), np.stack([np.sin(yaw), np.cos(yaw)], -1)], 1)
    t = rng.normal(0, spread_m, (H, 2))
    order = rng.permutation(H)
    for n in (1, 2, 8, 50):
        got = distinct_best(R, t, order, n, 1.5, 3.0)
        assert got.tolist() == _greedy(R, t, order, n, 1.5, 3.0)
