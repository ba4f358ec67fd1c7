"""The `constrained` aligner: matched vehicles, background and heading prior in one least-squares fit.

Starts from the matcher's transform when it gives one, from a weighted Kabsch on the
matched vehicles, and, when the matcher gives no transform, from each matched pair alone
under each velocity-heading yaw (a pair whose shared points belong to something else
cannot then spoil every start). Each start is refined by Gauss-Newton (refine.py) in which only the matched pairs
may act as vehicle terms, each weighted by its two views' line-of-sight covariances, so a
pair seen from two directions pins the vehicle where the rays cross; the background
(trimmed nearest neighbours) and the heading prior hold the rest. The start whose result
puts most of the other view's background on the own view's wins.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from mmatch.ego.base import AlignResult, MatchResult, heading_yaws
from mmatch.ego.descriptor_scale import scaled_distance
from mmatch.ego.observations import ObservationModel, mahalanobis, observe
from mmatch.ego.refine import RefineConfig, refine_many
from mmatch.ego.rigid import kabsch2d, se2_to_matrix
from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class ConstrainedConfig:
    observation: ObservationModel = ObservationModel()
    refine: RefineConfig = field(default_factory=lambda: RefineConfig(
        iterations=8, vehicle_gate=6.0, desc_gate=1.01, bg_weight_total=16.0))   # background weighs 16 vehicles
    score_gate_m: float = 1.0           # background points within this count as agreeing
    max_single_pair_starts: int = 8     # up to this many pairs, each also starts a fit alone
    kabsch_with_hint: bool = False      # also start from Kabsch when the matcher gives a transform


class ConstrainedAligner:
    name = "constrained"

    def __init__(self, config: ConstrainedConfig = ConstrainedConfig()) -> None:
        self.cfg = config

    def __call__(self, own: SharedFrame, other: SharedFrame, match: MatchResult) -> AlignResult:
        cfg = self.cfg
        A, B = observe(own, cfg.observation), observe(other, cfg.observation)
        pairs = match.pairs
        yaws = heading_yaws(own, other)
        starts: list[tuple[np.ndarray, np.ndarray]] = []
        if match.T_hint is not None:
            starts.append((match.T_hint[:2, :2], match.T_hint[:2, 3]))
        if len(pairs) >= 2 and (match.T_hint is None or cfg.kabsch_with_hint):
            w = 1.0 / np.array([np.trace(A.cov[i]) + np.trace(B.cov[j]) for i, j in pairs])
            starts.append(kabsch2d(B.centres[pairs[:, 1]], A.centres[pairs[:, 0]], w))
        if match.T_hint is None and yaws is not None and len(pairs) <= cfg.max_single_pair_starts:
            # each pair under each heading yaw: a start that one badly placed pair cannot spoil
            for i, j in pairs:
                for y in yaws:
                    R = np.array([[np.cos(y), -np.sin(y)], [np.sin(y), np.cos(y)]])
                    starts.append((R, A.centres[i] - R @ B.centres[j]))
        if not starts:
            return AlignResult(None, f"{len(pairs)} matched vehicle(s) and no usable hint")
        allowed = np.zeros((len(A.centres), len(B.centres)), bool)
        allowed[pairs[:, 0], pairs[:, 1]] = True
        D = scaled_distance(own.vehicle_features, other.vehicle_features, match.descriptor_scale)
        bg_own, bg_other = own.background[:, :2], other.background[:, :2]
        tree = cKDTree(bg_own) if len(bg_own) >= 3 else None
        Rs, ts = refine_many(A, B, D, bg_own, bg_other, np.stack([r for r, _ in starts]),
                             np.stack([x for _, x in starts]), yaws, cfg.refine, tree, allowed)
        best, best_score = None, -np.inf
        for R, t in zip(Rs, ts):
            if not np.all(np.isfinite(t)):
                continue
            score = _agreement(A, B, pairs, R, t, bg_other, tree, cfg)
            if score > best_score + 1e-9:
                best, best_score = (R, t), score
        if best is None:
            return AlignResult(None, "alignment diverged")
        R, t = best
        inl = 0.0
        if tree is not None and len(bg_other):
            d, _ = tree.query(bg_other @ R.T + t, distance_upper_bound=cfg.score_gate_m)
            inl = float(np.isfinite(d).mean())
        return AlignResult(se2_to_matrix(R, t, other.radar_height - own.radar_height), inlier_share=inl)


def _agreement(A, B, pairs, R, t, bg_other, tree, cfg) -> float:
    """Matched pairs explained (within 3 sigma) plus the background share within the gate."""
    s = 0.0
    if len(pairs):
        dm = mahalanobis(A, B, R[None], t[None])[0][pairs[:, 0], pairs[:, 1]]
        s += float(np.sum(np.clip(1 - dm / 3.0, 0, None)))
    if tree is not None and len(bg_other):
        d, _ = tree.query(bg_other @ R.T + t, distance_upper_bound=cfg.score_gate_m)
        s += 3.0 * float(np.isfinite(d).mean())
    return s
