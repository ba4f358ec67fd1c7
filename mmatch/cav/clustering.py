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
    if cfg.range_window_m > 0:
        keep &= _in_range_window(xy, vehicle, keep, cfg.range_window_m)
    if cfg.wheel_band_mps > 0:
        keep |= _wheel_returns(xy, residual, vehicle, keep, cfg)
    return keep


def _in_range_window(xy: np.ndarray, vehicle: np.ndarray, keep: np.ndarray, window_m: float) -> np.ndarray:
    """Which kept points (K,) lie in their vehicle's densest range window of window_m metres.

    A radar measures range far better than azimuth (centimetres against a degree or two), and
    one vehicle's returns span at most its body along the line of sight: returns of a vehicle
    behind it or of the roadside at other ranges fall outside. Ties: the window with the
    nearest returns.
    """
    out = np.ones(len(xy), bool)
    r = np.hypot(xy[:, 0], xy[:, 1])
    for v in np.unique(vehicle[keep]):
        idx = np.flatnonzero(keep & (vehicle == v))
        if len(idx) < 3:
            continue
        rs = np.sort(r[idx])
        counts = np.searchsorted(rs, rs + window_m, "right") - np.arange(len(rs))
        start = rs[int(np.argmax(counts))]
        out[idx] = (r[idx] >= start - 1e-9) & (r[idx] <= start + window_m)
    return out


def _wheel_returns(xy: np.ndarray, residual: np.ndarray, vehicle: np.ndarray, keep: np.ndarray,
                   cfg: ClusteringConfig) -> np.ndarray:
    """Points left out of their vehicle's main cluster that are its wheels: within eps_m of the
    cluster in position, with a residual between 0 and twice the cluster's median (a wheel's
    surface moves at 0 ... 2 x the body speed), give or take wheel_band_mps."""
    out = np.zeros(len(xy), bool)
    rest = np.flatnonzero(~keep)
    if len(rest) == 0:
        return out
    for v in np.unique(vehicle[rest]):
        core = np.flatnonzero(keep & (vehicle == v))
        if len(core) == 0:
            continue
        med = float(np.median(residual[core]))
        lo, hi = min(0.0, 2 * med) - cfg.wheel_band_mps, max(0.0, 2 * med) + cfg.wheel_band_mps
        cand = rest[vehicle[rest] == v]
        near = np.min(np.linalg.norm(xy[cand, None] - xy[None, core], axis=2), axis=1) <= cfg.eps_m
        out[cand[near & (residual[cand] >= lo) & (residual[cand] <= hi)]] = True
    return out
