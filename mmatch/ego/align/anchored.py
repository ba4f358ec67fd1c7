"""The `anchored-icp` aligner: background ICP held in place by the matched vehicles.

Initial transform: Kabsch on the matched vehicles' far-side-corrected centres (or the
matcher's hint when only one pair exists). Then ICP of the CAV background onto the
Ego background in which every matched vehicle is a fixed, heavily weighted
correspondence, so the fit cannot slide along a symmetric road. Finally the yaw is
blended with the velocity-heading prior (the two radars' own velocities, roads at right
angles) and the translation refitted with that yaw held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.ego.base import AlignResult, MatchResult, far_side_centres, heading_yaws
from mmatch.ego.rigid import icp2d, kabsch2d, se2_to_matrix
from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class AnchoredConfig:
    anchor_weight_share: float = 0.08   # each vehicle weighs this share of the background points
    min_anchor_weight: float = 4.0
    max_dist_m: float = 1.5
    min_dist_m: float = 0.5
    iterations: int = 30
    heading_sigma_deg: float = 2.5      # spread of the velocity-heading prior (lane wobble, curvature)
    icp_yaw_sigma_deg: float = 3.0      # spread of the ICP yaw on sparse, partly shared backgrounds
    heading_gate_deg: float = 10.0      # farther than this from every prior yaw: ignore the prior


class AnchoredICPAligner:
    name = "anchored-icp"

    def __init__(self, config: AnchoredConfig = AnchoredConfig()) -> None:
        self.cfg = config

    def __call__(self, own: SharedFrame, other: SharedFrame, match: MatchResult) -> AlignResult:
        A, B = far_side_centres(own), far_side_centres(other)
        pairs = match.pairs
        if len(pairs) >= 2:
            R, t = kabsch2d(B[pairs[:, 1]], A[pairs[:, 0]])
        elif match.T_hint is not None and len(pairs) == 1:
            R, t = match.T_hint[:2, :2], match.T_hint[:2, 3]
        else:
            return AlignResult(None, f"{len(pairs)} matched vehicle(s) and no usable hint")
        src, dst = other.background[:, :2], own.background[:, :2]
        w = max(self.cfg.min_anchor_weight, self.cfg.anchor_weight_share * len(src))
        anchors = (B[pairs[:, 1]], A[pairs[:, 0]]) if len(pairs) else None
        R, t, inl = icp2d(src, dst, R, t, self.cfg.max_dist_m, self.cfg.min_dist_m, self.cfg.iterations,
                          anchors=anchors, anchor_weight=w)
        yaws = heading_yaws(own, other)
        if yaws is not None:
            yaw = np.arctan2(R[1, 0], R[0, 0])
            d = (yaw - yaws + np.pi) % (2 * np.pi) - np.pi
            k = int(np.argmin(np.abs(d)))
            if abs(d[k]) < np.radians(self.cfg.heading_gate_deg):
                wp, wi = self.cfg.heading_sigma_deg ** -2, self.cfg.icp_yaw_sigma_deg ** -2
                fused = yaw - d[k] * wp / (wp + wi)
                R = np.array([[np.cos(fused), -np.sin(fused)], [np.sin(fused), np.cos(fused)]])
                R, t, inl = icp2d(src, dst, R, t, self.cfg.min_dist_m * 2, self.cfg.min_dist_m,
                                  self.cfg.iterations // 2, anchors=anchors, anchor_weight=w, fix_rotation=True)
        if not np.all(np.isfinite(t)):
            return AlignResult(None, "alignment diverged")
        return AlignResult(se2_to_matrix(R, t, other.radar_height - own.radar_height), inlier_share=inl)
