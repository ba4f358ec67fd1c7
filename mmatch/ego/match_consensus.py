"""The `consensus` matcher: appearance plus pairwise-geometry consensus, one-to-one by Hungarian.

No learning. Every two candidate pairs whose inter-vehicle distances agree define a
planar CAV -> Ego transform; each hypothesis is scored by how many other vehicles land
on a look-alike partner and by how much of the CAV's stationary background lands on
the Ego's. The best hypothesis is refined on its inlier vehicles, and the final pairs
are the Hungarian assignment under it, gated in distance and appearance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from mmatch.ego.base import (MatchContext, MatchResult, descriptor_distance, far_side_centres, heading_yaws,
                             road_speed_consistency)
from mmatch.ego.rigid import kabsch2d, se2_to_matrix
from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class ConsensusConfig:
    """Gates in metres and descriptor (Hellinger, 0-1) units."""

    candidates_per_vehicle: int = 6      # look-alike candidates kept per vehicle
    pair_dist_tol_m: float = 2.5         # inter-vehicle distance agreement
    pair_dist_tol_rel: float = 0.06
    min_baseline_m: float = 2.0          # the two vehicles of a hypothesis must be this far apart
    inlier_m: float = 3.5                # a vehicle lands on its partner within this
    desc_weight: float = 1.5             # appearance share of the assignment cost
    desc_gate: float = 0.55              # pairs less alike than this are never matched
    background_weight: float = 3.0       # background agreement, in vehicle-match units
    background_gate_m: float = 1.0
    background_points: int = 150         # background points used for scoring
    top_hypotheses: int = 40             # hypotheses that get the background score
    yaw_gate_deg: float = 10.0           # hypotheses this far from every velocity-heading yaw are dropped
    camera_half_fov_deg: float = 30.0    # where a vehicle is expected to be detected by the other camera
    camera_range_m: float = 70.0
    miss_weight: float = 0.1             # per vehicle that the other camera should see but did not
    sighting_weight: float = 1.0         # the other vehicle itself found where the hypothesis puts it
    body_offset_m: float = 2.3           # radar (front bumper) to vehicle centre
    speed_weight: float = 0.5            # road-speed agreement (+1 / 0 / -1) in likeness units


class ConsensusMatcher:
    name = "consensus"

    def __init__(self, config: ConsensusConfig = ConsensusConfig()) -> None:
        self.cfg = config

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        cfg = self.cfg
        A, B = far_side_centres(own), far_side_centres(other)
        if len(A) == 0 or len(B) == 0:
            return MatchResult()
        D = descriptor_distance(own.vehicle_features, other.vehicle_features)
        cand = _candidates(D, cfg.candidates_per_vehicle, cfg.desc_gate)
        hyps = _pair_hypotheses(A, B, cand, cfg)
        if len(hyps[0]) == 0:
            return MatchResult()
        R, t = hyps
        yaws = heading_yaws(own, other)
        speed = road_speed_consistency(own, other)
        m_idx = None
        if yaws is not None:
            gap = np.abs((np.arctan2(R[:, 1, 0], R[:, 0, 0])[:, None] - yaws + np.pi) % (2 * np.pi) - np.pi)
            keep = gap.min(axis=1) < np.radians(cfg.yaw_gate_deg)
            if keep.any():
                R, t, gap = R[keep], t[keep], gap[keep]
            m_idx = gap.argmin(axis=1)
        alike = np.clip(1 - D / cfg.desc_gate, 0, None)[None]
        if speed is not None and m_idx is not None:
            alike = alike + cfg.speed_weight * speed[m_idx]
        veh_score = _vehicle_scores(A, B, alike, R, t, cfg)
        top = np.argsort(-veh_score)[: cfg.top_hypotheses]
        bg = _background_scores(own.background, other.background, R[top], t[top], cfg)
        total = veh_score[top] + cfg.background_weight * bg
        best = top[int(np.argmax(total))]
        R_b, t_b = R[best], t[best]
        veto = speed[m_idx[best]] < 0 if speed is not None and m_idx is not None else None
        pairs, cost = _assign(A, B, D, R_b, t_b, cfg, veto)
        if len(pairs) >= 2:
            R_b, t_b = kabsch2d(B[pairs[:, 1]], A[pairs[:, 0]])
            pairs, cost = _assign(A, B, D, R_b, t_b, cfg, veto)
        T = se2_to_matrix(R_b, t_b, other.radar_height - own.radar_height)
        return MatchResult(pairs=pairs, scores=1.0 - cost, T_hint=T)


def _candidates(D: np.ndarray, k: int, gate: float) -> np.ndarray:
    """(C, 2) candidate (own, other) pairs: mutual top-k look-alikes under the gate."""
    Va, Vb = D.shape
    keep = np.zeros_like(D, bool)
    ra = np.argsort(D, axis=1)[:, :k]
    keep[np.repeat(np.arange(Va), ra.shape[1]), ra.ravel()] = True
    rb = np.argsort(D, axis=0)[:k, :]
    keep[rb.ravel(), np.tile(np.arange(Vb), rb.shape[0])] = True
    keep &= D < gate
    return np.argwhere(keep)


def _pair_hypotheses(A, B, cand, cfg):
    """Transforms (H, 2, 2), (H, 2) from every two compatible candidate pairs."""
    if len(cand) < 2:
        if len(cand) == 1:   # one pair: identity rotation placed on it (a weak hypothesis)
            i, j = cand[0]
            return np.eye(2)[None], (A[i] - B[j])[None]
        return np.zeros((0, 2, 2)), np.zeros((0, 2))
    p, q = np.triu_indices(len(cand), 1)
    i, j, k, l = cand[p, 0], cand[p, 1], cand[q, 0], cand[q, 1]
    ok = (i != k) & (j != l)
    da = np.linalg.norm(A[i] - A[k], axis=1)
    db = np.linalg.norm(B[j] - B[l], axis=1)
    ok &= (np.abs(da - db) < cfg.pair_dist_tol_m + cfg.pair_dist_tol_rel * da) & (da > cfg.min_baseline_m)
    i, j, k, l = i[ok], j[ok], k[ok], l[ok]
    va, vb = A[k] - A[i], B[l] - B[j]
    ang = np.arctan2(va[:, 1], va[:, 0]) - np.arctan2(vb[:, 1], vb[:, 0])
    c, s = np.cos(ang), np.sin(ang)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)
    mid_a, mid_b = (A[i] + A[k]) / 2, (B[j] + B[l]) / 2
    t = mid_a - np.einsum("hij,hj->hi", R, mid_b)
    return R, t


def _in_view(p: np.ndarray, cfg: ConsensusConfig) -> np.ndarray:
    """Whether points (..., 2) in a radar frame lie where that vehicle's camera detects vehicles."""
    r = np.linalg.norm(p, axis=-1)
    az = np.abs(np.arctan2(p[..., 0], p[..., 1]))
    return (r > 4.0) & (r < cfg.camera_range_m) & (az < np.radians(cfg.camera_half_fov_deg))


def _vehicle_scores(A, B, alike, R, t, cfg):
    """(H,) evidence for each hypothesis from the vehicles alone.

    + each Ego vehicle landing near a look-alike CAV vehicle (closeness x likeness);
    - each vehicle the other camera should have seen, unmatched (misses cost less than
      wrong matches: occlusion hides some);
    + the other vehicle itself among the detections where the hypothesis puts it.
    """
    Bt = np.einsum("hij,vj->hvi", R, B) + t[:, None]               # (H, Vb, 2) CAV vehicles in Ego frame
    dist = np.linalg.norm(A[None, :, None] - Bt[:, None], axis=3)   # (H, Va, Vb)
    close = np.clip(1 - dist / cfg.inlier_m, 0, None)
    score = (close * np.clip(0.5 + alike, 0, None)).max(axis=2).sum(axis=1)
    body = np.array([0.0, -cfg.body_offset_m])
    cav_body = np.einsum("hij,j->hi", R, body) + t                  # (H, 2) CAV centre in Ego frame
    A_in_cav = np.einsum("hji,hvj->hvi", R, A[None] - t[:, None])  # (H, Va, 2) Ego vehicles in CAV frame
    ego_body_in_cav = np.einsum("hji,hj->hi", R, body[None] - t)    # (H, 2)
    a_is_cav = np.linalg.norm(A[None] - cav_body[:, None], axis=2) < cfg.inlier_m
    b_is_ego = np.linalg.norm(Bt - body, axis=2) < cfg.inlier_m
    a_unpaired = dist.min(axis=2) > cfg.inlier_m
    b_unpaired = dist.min(axis=1) > cfg.inlier_m
    miss = (a_unpaired & _in_view(A_in_cav, cfg) & ~a_is_cav).sum(1) \
        + (b_unpaired & _in_view(Bt, cfg) & ~b_is_ego).sum(1)
    seen = a_is_cav.any(1).astype(float) * _in_view(cav_body, cfg) \
        + b_is_ego.any(1).astype(float) * _in_view(ego_body_in_cav, cfg)
    return score - cfg.miss_weight * miss + cfg.sighting_weight * seen


def _background_scores(bg_own, bg_other, R, t, cfg):
    """(H,) share of the CAV's background landing within the gate of the Ego's."""
    if len(bg_own) < 3 or len(bg_other) < 3:
        return np.zeros(len(R))
    rng = np.random.default_rng(0)
    src = bg_other[:, :2]
    if len(src) > cfg.background_points:
        src = src[rng.choice(len(src), cfg.background_points, replace=False)]
    tree = cKDTree(bg_own[:, :2])
    moved = np.einsum("hij,nj->hni", R, src) + t[:, None]
    d, _ = tree.query(moved.reshape(-1, 2), distance_upper_bound=cfg.background_gate_m)
    return np.isfinite(d).reshape(len(R), -1).mean(axis=1)


def _assign(A, B, D, R, t, cfg, veto=None):
    """One-to-one pairs under a transform: Hungarian on distance + appearance, gated (and vetoed)."""
    Bt = B @ R.T + t
    dist = np.linalg.norm(A[:, None] - Bt[None], axis=2)
    cost = dist / cfg.inlier_m + cfg.desc_weight * D
    big = 1e6
    allowed = (dist < cfg.inlier_m) & (D < cfg.desc_gate)
    if veto is not None:
        allowed &= ~veto
    gated = np.where(allowed, cost, big)
    r, c = linear_sum_assignment(gated)
    ok = gated[r, c] < big
    pairs = np.column_stack([r[ok], c[ok]]).astype(np.int32)
    return pairs, cost[r[ok], c[ok]] / (1 + cfg.desc_weight)
