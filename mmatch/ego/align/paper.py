"""The `paper` aligner: the paper's two-stage alignment as it is written.

Stage 1, co-visible vehicles: point-to-point ICP on the matched vehicles' radar points,
each vehicle's points paired only with its partner's, every correspondence of pair n
weighted w_n = exp(score_n) (score_n: the matcher's pair score, 0-1), from a Kabsch fit of
the pairs' centroids with the same weights. Stage 2, global: the same pair terms plus the
stationary background (nearest neighbours within a shrinking gate), every background
correspondence weighted w_g = exp(1 / N_v) with N_v the number of co-visible vehicles, so
the background counts for more when few vehicles are shared.

What the paper leaves open is filled as the ablation aligners do (icp_ablation.py: gates,
trim, iterations), so `paper` and `icp-pair` differ only by the weights and the second
stage. Needs two matched vehicles. Frames: CAV and Ego radar frames, metres, SE(2).
"""

from __future__ import annotations

import numpy as np

from mmatch.ego.align.grouped_icp import PointSet, grouped_icp
from mmatch.ego.align.icp_ablation import AblationConfig, centroid_start, pair_points
from mmatch.ego.base import AlignResult, MatchResult
from mmatch.ego.rigid import se2_to_matrix
from mmatch.shared import SharedFrame


class PaperAligner:
    name = "paper"

    def __init__(self, config: AblationConfig = AblationConfig()) -> None:
        self.cfg = config

    def __call__(self, own: SharedFrame, other: SharedFrame, match: MatchResult) -> AlignResult:
        c = self.cfg
        pairs = np.asarray(match.pairs).reshape(-1, 2)
        n_v = len(pairs)
        if n_v < 2:
            return AlignResult(None, f"{n_v} matched vehicle(s); the paper's alignment needs 2")
        scores = np.asarray(match.scores, np.float64).reshape(-1)
        if len(scores) != n_v or not np.all(np.isfinite(scores)):
            scores = np.ones(n_v)
        w_n = np.exp(np.clip(scores, 0.0, 1.0))
        a_xy, a_g, b_xy, b_g = pair_points(own, other, pairs)
        vehicles = PointSet(b_xy, a_xy, b_g, a_g, w_n[b_g], c.pair_gate_m, c.pair_gate_m, c.trim)
        R, t = centroid_start(own, other, pairs, w_n)
        R, t, _ = grouped_icp([vehicles], R, t, c.iterations)
        background = PointSet.ungrouped(other.background[:, :2], own.background[:, :2], c.max_dist_m,
                                        c.min_dist_m, c.trim, weight=float(np.exp(1.0 / n_v)))
        R, t, inl = grouped_icp([vehicles, background], R, t, c.iterations)
        if not np.all(np.isfinite(t)):
            return AlignResult(None, "alignment diverged")
        return AlignResult(se2_to_matrix(R, t, other.radar_height - own.radar_height), inlier_share=inl)
