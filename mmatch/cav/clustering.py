"""DBSCAN per vehicle over (x, y, scaled Doppler residual): keep each vehicle's main cluster.

All vehicles go through one DBSCAN call (`mmatch.cav.dbscan`): the vehicle index is appended as a
coordinate scaled far beyond eps, so clusters never span two vehicles. The main cluster of
a vehicle is the one with the most moving points (ties: the most points, then the lowest
label); a vehicle without moving points keeps its largest cluster.
"""

from __future__ import annotations

import numpy as np

from mmatch.cav.config import ClusteringConfig
from mmatch.cav.dbscan import dbscan_labels

_SEPARATE = 1.0e6          # metres between two vehicles' slices of the feature space


def main_clusters(xy: np.ndarray, residual: np.ndarray, moving: np.ndarray, vehicle: np.ndarray,
                  config: ClusteringConfig | None = None) -> np.ndarray:
    """Which points (K,) stay with their vehicle.

    xy: (K, 2) positions, m (radar frame); residual: (K,) Doppler minus the stationary
    prediction, m/s; moving: bool (K,); vehicle: int (K,) vehicle index >= 0.
    Returns bool (K,): True for the points of each vehicle's main cluster.
    """
    cfg = config or ClusteringConfig()
    k = len(xy)
    if k == 0:
        return np.zeros(0, bool)
    feats = np.column_stack([xy[:, 0], xy[:, 1], cfg.velocity_scale_s * residual,
                             _SEPARATE * vehicle.astype(np.float64)])
    labels = dbscan_labels(feats, cfg.eps_m, cfg.min_samples)
    ok = labels >= 0
    if not ok.any():
        return ok
    lab = labels[ok]
    n_lab = int(lab.max()) + 1
    size = np.bincount(lab, minlength=n_lab)
    n_mov = np.bincount(lab, weights=moving[ok].astype(np.float64), minlength=n_lab)
    owner = np.zeros(n_lab, np.int64)
    owner[lab] = vehicle[ok]                          # each cluster lies in one vehicle
    # rank clusters inside each vehicle: most moving points, then most points, then lowest label
    order = np.lexsort((np.arange(n_lab), -size, -n_mov, owner))
    first = np.ones(n_lab, bool)
    first[1:] = owner[order][1:] != owner[order][:-1]
    best = np.zeros(n_lab, bool)
    best[order[first]] = True
    keep = np.zeros(k, bool)
    keep[ok] = best[lab]
    return keep
