"""The `centroid-icp` aligner (the yardstick): Kabsch on the matched vehicles' point centroids,
then point-to-point ICP of the CAV background onto the Ego background."""

from __future__ import annotations

from mmatch.ego.base import AlignResult, MatchResult, vehicle_centroids
from mmatch.ego.rigid import icp2d, kabsch2d, se2_to_matrix
from mmatch.shared import SharedFrame


class CentroidICPAligner:
    name = "centroid-icp"

    def __call__(self, own: SharedFrame, other: SharedFrame, match: MatchResult) -> AlignResult:
        if len(match.pairs) < 2:
            return AlignResult(None, f"{len(match.pairs)} matched vehicle(s); centroid Kabsch needs 2")
        A, B = vehicle_centroids(own), vehicle_centroids(other)
        R, t = kabsch2d(B[match.pairs[:, 1]], A[match.pairs[:, 0]])
        R, t, inl = icp2d(other.background[:, :2], own.background[:, :2], R, t)
        return AlignResult(se2_to_matrix(R, t, other.radar_height - own.radar_height), inlier_share=inl)
