"""The paper's alignment ablation: point-to-point ICP on one kind of shared points at a time.

`icp-all` (every shared point: vehicles and background), `icp-bg` (background only),
`icp-veh` (every vehicle point, any vehicle with any), `icp-pair` (the matched vehicles only,
each vehicle's points paired only with its partner's). All four start from the same place,
a Kabsch fit of the matched vehicles' centroids, and run the same ICP (grouped_icp.py), so a
difference between them is what the chosen points contribute. Without two matched
vehicles there is no start and no estimate (as for the `centroid-icp` yardstick); ICP from
the identity is what the point-cloud peers do (baselines.py).

Frames: the CAV and Ego radar frames (x right, y forward), metres; the fit is SE(2) and the
z offset is the difference of the two mounting heights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.ego.align.grouped_icp import PointSet, grouped_icp
from mmatch.ego.base import AlignResult, MatchResult, vehicle_centroids
from mmatch.ego.rigid import kabsch2d, se2_to_matrix
from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class AblationConfig:
    """max_dist_m / min_dist_m: ICP gate between unrelated points (shrinks over the rounds);
    pair_gate_m: gate inside a matched pair (the two radars see different faces of a car);
    trim: share of the closest correspondences kept each round."""

    max_dist_m: float = 3.0
    min_dist_m: float = 0.5
    pair_gate_m: float = 8.0
    iterations: int = 30
    trim: float = 0.8


def pair_points(own: SharedFrame, other: SharedFrame, pairs: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points of the matched vehicles grouped by pair: (own xy, own pair, other xy, other pair).

    Pair n = (i, j) gives own vehicle i's points and other vehicle j's points group n; a
    vehicle without radar points contributes its centroid (the camera's centre).
    """
    ca, cb = vehicle_centroids(own), vehicle_centroids(other)

    def side(frame: SharedFrame, col: np.ndarray, centres: np.ndarray):
        idx = np.asarray(frame.vehicle_index)
        pos = np.full(frame.num_vehicles, -1)
        pos[col] = np.arange(len(col))
        group = pos[idx] if len(idx) else np.zeros(0, int)
        keep = group >= 0
        xy, g = frame.vehicle_points[keep, :2].astype(np.float64), group[keep]
        empty = np.setdiff1d(np.arange(len(col)), g)
        return np.vstack([xy, centres[col[empty]]]), np.concatenate([g, empty])

    a_xy, a_g = side(own, pairs[:, 0], ca)
    b_xy, b_g = side(other, pairs[:, 1], cb)
    return a_xy, a_g, b_xy, b_g


def centroid_start(own: SharedFrame, other: SharedFrame, pairs: np.ndarray,
                   weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) other -> own from a (weighted) Kabsch fit of the matched vehicles' centroids."""
    A, B = vehicle_centroids(own), vehicle_centroids(other)
    return kabsch2d(B[pairs[:, 1]], A[pairs[:, 0]], weights)


def all_vehicle_points(frame: SharedFrame) -> np.ndarray:
    """(K, 2) x, y of every shared vehicle point."""
    return frame.vehicle_points[:, :2].astype(np.float64)


class _AblationAligner:
    """Common body: the centroid start, then grouped ICP on the sets `point_sets` returns."""

    name = ""

    def __init__(self, config: AblationConfig = AblationConfig()) -> None:
        self.cfg = config

    def point_sets(self, own: SharedFrame, other: SharedFrame, pairs: np.ndarray) -> list[PointSet]:
        raise NotImplementedError

    def __call__(self, own: SharedFrame, other: SharedFrame, match: MatchResult) -> AlignResult:
        pairs = np.asarray(match.pairs).reshape(-1, 2)
        if len(pairs) < 2:
            return AlignResult(None, f"{len(pairs)} matched vehicle(s); the centroid start needs 2")
        R, t = centroid_start(own, other, pairs)
        R, t, inl = grouped_icp(self.point_sets(own, other, pairs), R, t, self.cfg.iterations)
        if not np.all(np.isfinite(t)):
            return AlignResult(None, "alignment diverged")
        return AlignResult(se2_to_matrix(R, t, other.radar_height - own.radar_height), inlier_share=inl)

    def _free(self, src: np.ndarray, dst: np.ndarray) -> PointSet:
        c = self.cfg
        return PointSet.ungrouped(src, dst, c.max_dist_m, c.min_dist_m, c.trim)


class ICPAllAligner(_AblationAligner):
    name = "icp-all"

    def point_sets(self, own, other, pairs):
        return [self._free(np.vstack([all_vehicle_points(other), other.background[:, :2]]),
                           np.vstack([all_vehicle_points(own), own.background[:, :2]]))]


class ICPBackgroundAligner(_AblationAligner):
    name = "icp-bg"

    def point_sets(self, own, other, pairs):
        return [self._free(other.background[:, :2], own.background[:, :2])]


class ICPVehicleAligner(_AblationAligner):
    name = "icp-veh"

    def point_sets(self, own, other, pairs):
        return [self._free(all_vehicle_points(other), all_vehicle_points(own))]


class ICPPairAligner(_AblationAligner):
    name = "icp-pair"

    def point_sets(self, own, other, pairs):
        a_xy, a_g, b_xy, b_g = pair_points(own, other, pairs)
        c = self.cfg
        return [PointSet(b_xy, a_xy, b_g, a_g, np.ones(len(b_xy)), c.pair_gate_m, c.pair_gate_m, c.trim)]
