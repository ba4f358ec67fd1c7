"""The DBSCAN fast path gives scikit-learn's partition exactly."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from mmatch.cav.dbscan import dbscan_labels


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    if not np.array_equal(a < 0, b < 0):
        return False
    pairs = {(int(x), int(y)) for x, y in zip(a[a >= 0], b[b >= 0])}
    return len(pairs) == len(set(a[a >= 0])) == len(set(b[b >= 0]))


@pytest.mark.parametrize("min_samples", [1, 2, 3, 4])
@pytest.mark.parametrize("seed", range(6))
def test_same_clusters_as_scikit_learn(seed, min_samples):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 300))
    X = np.column_stack([rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.normal(0, 1, n)])
    X[: n // 4] = X[0] + rng.normal(0, 0.5, (n // 4, 3))       # one dense blob
    eps = float(rng.uniform(1, 4))
    ours = dbscan_labels(X, eps, min_samples)
    ref = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(X)
    assert same_partition(ours, ref)
    assert ours.max() + 1 == len(set(ours[ours >= 0]))         # numbered 0..k-1


def test_distance_exactly_eps_is_a_neighbour_and_empty_input():
    X = np.array([[0.0, 0.0], [2.0, 0.0], [10.0, 0.0]])
    assert dbscan_labels(X, 2.0, 2).tolist() == [0, 0, -1]
    assert dbscan_labels(X, 2.0, 1).tolist() == [0, 0, 1]
    assert dbscan_labels(np.zeros((0, 2)), 1.0, 2).shape == (0,)
