"""The `consensus` matcher: appearance plus pairwise-geometry consensus, one-to-one by Hungarian.

No learning. Every two candidate pairs whose inter-vehicle distances agree define a
planar CAV -> Ego transform; each hypothesis is scored by how many other vehicles land
on a look-alike partner and by how much of the CAV's stationary background lands on
the Ego's. The best hypothesis is refined on its inlier vehicles, and the final pairs
are the Hungarian assignment under it, gated in distance and appearance.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from mmatch.ego.base import (CROSS_BAND_DEG, Hypotheses, MatchContext, MatchResult, SightingModel,
                             background_tree, crossing_allowance, detection_scores, heading_yaws,
                             road_speed_consistency, sighting_gaps, sighting_offsets)
from mmatch.ego.descriptor_scale import scaled_distance
from mmatch.ego.observations import (ObservationModel, Observations, mahalanobis, observe,
                                     pair_major_mahalanobis)
from mmatch.ego.refine import RefineConfig, refine_many
from mmatch.ego.rigid import distinct_best, se2_to_matrix
from mmatch.numeric import lengths
from mmatch.shared import TYPICAL_SCORE, SharedFrame


@dataclass(frozen=True)
class ConsensusConfig:
    """Gates in metres, Mahalanobis units (sigma) and descriptor (Hellinger, 0-1) units."""

    candidates_per_vehicle: int = 6      # look-alike candidates kept per vehicle
    pair_dist_tol_m: float = 2.5         # inter-vehicle distance agreement
    pair_dist_tol_rel: float = 0.06
    min_baseline_m: float = 2.0          # the two vehicles of a hypothesis must be this far apart
    gate_sigma: float = 3.0              # a vehicle lands on its partner within this Mahalanobis distance
    assign_gate_sigma: float = 2.5       # the same for the final one-to-one pairs
    assign_min_score: float = 0.5        # detections scoring below this are never paired
    desc_weight: float = 1.5             # appearance share of the assignment cost
    desc_gate: float = 0.55              # pairs less alike than this are never matched
    desc_mid: float = 0.30               # descriptor distance where a pair is as likely the same as not
    desc_width: float = 0.1              # > 0: logistic likeness around desc_mid (else linear to the gate)
    background_weight: float = 3.0       # background agreement, in vehicle-match units
    background_gate_m: float = 1.0
    background_sigma_m: float = 0.0      # > 0: soft agreement exp(-d^2 / 2 sigma^2) instead of a hit
    background_in_view: bool = False     # share among the points the own radar can see
    background_min_seen: int = 10
    radar_half_fov_deg: float = 65.0
    radar_range_m: float = 100.0
    background_points: int = 150         # background points used for scoring
    coarse_budget: int = 400_000        # vehicle x vehicle evaluations of the coarse scoring: at
                                         # most this / (Va x Vb) two-pair hypotheses (at least 300)
                                         # and half as many single-pair ones, the most alike first,
                                         # so dense traffic cannot stall a frame (37.5 a view: 584 ->
                                         # 86 ms median, success 1.0 -> 0.95); frames of up to about
                                         # 15 vehicles a view stay below it (figures unchanged);
                                         # `rmnet` is the matcher for dense traffic
    refine_hypotheses: int = 12         # best coarse hypotheses refined and rescored (16 until
                                         # 2026-12-07, with `refine` at 6 rounds: see below)
    refine_with_prior: int = 4          # the same when a track predicts the transform (prior + 3)
    quick_iterations: int = 3           # refinement rounds of a tracking frame (prediction only)
    quick_background_weight: float = 10.0  # all background terms of a tracking frame's refinement
                                         # together weigh this many vehicles (refine.bg_weight_total
                                         # of a full search): near a good prediction the background
                                         # correspondences are right, so they can carry the fit
    distinct_m: float = 1.5              # hypotheses closer than this (and distinct_deg) count as one
    distinct_deg: float = 3.0
    yaw_gate_deg: float = 10.0           # hypotheses this far from every velocity-heading yaw are dropped
    cross_band_deg: float = CROSS_BAND_DEG  # ... unless within this much beyond the gate of a
                                         # crossing road's yaw (oblique junctions: crossing_allowance)
    off_grid_penalty: float = 1.0        # score taken from a hypothesis that lies off every heading
                                         # yaw (a crossing road's, inside the band), growing from 0
                                         # at the gate to all of it at off_grid_full_deg; such a
                                         # hypothesis weighs no road speeds (right angles assumed)
    off_grid_full_deg: float = 35.0
    sighting_hypotheses: bool = True     # each detection taken as the other vehicle itself, under each
                                         # heading yaw: a vehicle following another sees it even when
                                         # the two views share one vehicle or none; on since the
                                         # sighting polish (ego/align/constrained.py): wide hard
                                         # tuning seeds 1, 3, 4, 20-23 candidates right 0.823 ->
                                         # 0.835, grossly wrong 0.115 -> 0.110, gross at coverage
                                         # 0.8 45 -> 39 (with stress 43-44); matching +0.1-0.4 ms
    sighting_refine: int = 2             # the best of them refined beside refine_hypotheses
    camera_half_fov_deg: float = 30.0    # where a vehicle is expected to be detected by the other camera
    camera_range_m: float = 70.0
    miss_weight: float = 0.1             # per vehicle that the other camera should see but did not
    sighting_weight: float = 1.0         # the other vehicle itself found where the hypothesis puts it
    sighting_m: float = 3.5
    sighting: SightingModel = SightingModel()  # where a detection puts the radar of the vehicle it is
    speed_weight: float = 0.5            # road-speed agreement (+1 / 0 / -1) in likeness units
    pair_score_share: float = 0.0        # share of a pair-scoring network's score p (as 2 p - 0.5,
                                         # likeness units) in each pair's likeness, the rest
                                         # appearance; only a matcher with a network has one
                                         # (`consensus-rmnet`: 0.3, its module doc)
    typical_score: float = TYPICAL_SCORE  # a frame's median detection score is lifted to at least this
    score_low: float = 0.3               # detection scores map to confidence 0 ... 1 between these
    score_high: float = 0.8
    min_confidence: float = 0.25
    prior_weight: float = 0.0            # agreement with the track's prediction (MatchContext.prior_T);
                                         # 0: the pose filter weighs the prediction, a refinement
                                         # that also scored it would confirm it (ego/track/)
    prior_sigma_m: float = 1.5
    prior_sigma_deg: float = 3.0
    observation: ObservationModel = ObservationModel()
    refine: RefineConfig = RefineConfig(iterations=4)   # rounds of a full search's refinement
                                         # (6 until 2026-12-07): with 12 hypotheses and the
                                         # aligner's 5 rounds, per-frame Ego path 12.85 -> 11.3 ms
                                         # median (seed 2, one process); wide hard tuning seeds 1,
                                         # 3, 4, 20-23 success 0.711 -> 0.717, pair F1 0.930 ->
                                         # 0.931, gross at coverage 0.8 2.0 -> 1.8 %; held out
                                         # (2, 5-9, 14-16) 0.722 -> 0.721, 0.936 -> 0.937, 1.25 ->
                                         # 1.32 %; tracked drives 500-900 0.882 -> 0.883

    def tracking_refine(self) -> RefineConfig:
        """The refinement of a tracking frame (MatchContext.prior_only): fewer rounds, more
        background weight."""
        return replace(self.refine, iterations=self.quick_iterations, bg_weight_total=self.quick_background_weight)


class ConsensusMatcher:
    name = "consensus"
    pairs_from_transform = True     # the fused pairs are those the published transform implies (fusion.py)

    def __init__(self, config: ConsensusConfig = ConsensusConfig()) -> None:
        self.cfg = config

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        cfg = self.cfg
        A, B = observe(own, cfg.observation), observe(other, cfg.observation)
        if len(A.centres) == 0 or len(B.centres) == 0:
            return MatchResult()
        scale = 1.0 if ctx.descriptor_scale is None else ctx.descriptor_scale
        D = scaled_distance(own.vehicle_features, other.vehicle_features, scale)
        P = self.pair_scores(own, other) if cfg.pair_score_share > 0 else None
        cand = _candidates(D, cfg.candidates_per_vehicle, cfg.desc_gate)
        if ctx.prior_T is not None and ctx.prior_only:
            cand = cand[:0]                   # tracking frame: the prediction is the only hypothesis
        yaws = heading_yaws(own, other)
        allow = crossing_allowance(own, other, cfg.cross_band_deg)
        offsets = sighting_offsets(own, other, cfg.sighting)
        cost = D[cand[:, 0], cand[:, 1]]
        most = max(300, cfg.coarse_budget // max(len(A.centres) * len(B.centres), 1))
        R, t = _pair_hypotheses(A.centres, B.centres, cand, cfg, cost, most)
        if yaws is not None and len(cand):
            single = cand
            if len(cand) * len(yaws) > most // 2:      # each candidate under every yaw: the most alike
                n_single = max(1, most // 2 // len(yaws))
                single = cand[_most_alike(cost, n_single)]
            R1, t1 = _single_pair_hypotheses(A.centres, B.centres, single, yaws)
            R, t = np.concatenate([R, R1]), np.concatenate([t, t1])
        if yaws is not None and len(R):
            keep = _yaw_gap(R, yaws, allowance=allow) < np.radians(cfg.yaw_gate_deg)
            if keep.any():
                R, t = R[keep], t[keep]
        n_regular = len(R)
        if yaws is not None and cfg.sighting_hypotheses and ctx.prior_T is None:
            R2, t2 = _sighting_hypotheses(A.centres, B.centres, yaws, *offsets)
            R, t = np.concatenate([R, R2]), np.concatenate([t, t2])
        n_sighting = len(R) - n_regular
        prior = ctx.prior_T
        if prior is not None:            # the track's prediction always competes
            R, t = np.concatenate([R, prior[None, :2, :2]]), np.concatenate([t, prior[None, :2, 3]])
        if len(R) == 0:
            return MatchResult()
        speed = road_speed_consistency(own, other)
        off_grid = functools.partial(_off_grid, yaws=yaws, allowance=allow, cfg=cfg)
        alike_of = _likeness(D, yaws, speed, cfg, _confidence(own, cfg), _confidence(other, cfg), P,
                             allow)
        veh_score = _vehicle_scores(A, B, alike_of(R), R, t, cfg, offsets)
        rank, n_refine = veh_score, cfg.refine_hypotheses
        if prior is not None:
            rank = np.concatenate([veh_score[:-1], [np.inf]])
            n_refine = cfg.refine_with_prior
        sighted = np.zeros(len(R), bool)
        sighted[n_regular:n_regular + n_sighting] = True
        order = best_first(rank, t)
        top = distinct_best(R, t, order[~sighted[order]], n_refine, cfg.distinct_m, cfg.distinct_deg)
        if n_sighting and cfg.sighting_refine:           # slots of their own: they never displace a pair's
            top = np.concatenate([top, distinct_best(R, t, order[sighted[order]], cfg.sighting_refine,
                                                     cfg.distinct_m, cfg.distinct_deg)])
        bg_own, bg_other = own.background[:, :2], other.background[:, :2]
        tree = background_tree(own)
        rcfg = cfg.tracking_refine() if ctx.prior_only and prior is not None else cfg.refine
        R_ref, t_ref = refine_many(A, B, D, bg_own, bg_other, R[top], t[top], yaws, rcfg, tree)
        Rr, tr = np.concatenate([R[top], R_ref]), np.concatenate([t[top], t_ref])
        # the unrefined hypotheses' vehicle scores are the coarse ones (row by row the same)
        refined = _vehicle_scores(A, B, alike_of(R_ref), R_ref, t_ref, cfg, offsets)
        total = np.concatenate([veh_score[top], refined]) \
            + cfg.background_weight * _background_scores(bg_own, bg_other, Rr, tr, cfg, tree) \
            - cfg.off_grid_penalty * off_grid(Rr)
        if prior is not None and cfg.prior_weight:
            total = total + cfg.prior_weight * _prior_agreement(Rr, tr, prior, cfg)
        best = int(np.argmax(total))
        R_b, t_b = Rr[best], tr[best]
        veto = None
        if speed is not None and yaws is not None:
            nearest, off = _nearest_heading(R_b[None], yaws, allow, cfg)
            veto = None if off[0] else speed[nearest[0]] < 0
        pairs, cost = _assign(A, B, D, R_b, t_b, cfg, veto, _scores(own, cfg), _scores(other, cfg))
        T = se2_to_matrix(R_b, t_b, other.radar_height - own.radar_height)
        return MatchResult(pairs=pairs, scores=1.0 - cost, T_hint=T, descriptor_scale=scale,
                           hypotheses=Hypotheses(Rr, tr, total))

    def pair_scores(self, own: SharedFrame, other: SharedFrame) -> np.ndarray | None:
        """(Va, Vb) 0-1 scores of each pair being one vehicle from a network that sees both
        frames, weighed into the likeness (`pair_score_share`); None: this matcher has none."""
        return None

    def pairs_under(self, own: SharedFrame, other: SharedFrame, R: np.ndarray, t: np.ndarray,
                    descriptor_scale: float = 1.0, observed: tuple | None = None,
                    dist: np.ndarray | None = None) -> np.ndarray:
        """(P, 2) the one-to-one pairs this matcher assigns under one transform R (2, 2), t (2,).

        observed: the two frames' Observations when already at hand (same observation model);
        dist: their (Va, Vb) Mahalanobis distances under R, t when at hand."""
        cfg = self.cfg
        A, B = observed if observed is not None else (observe(own, cfg.observation), observe(other, cfg.observation))
        if len(A.centres) == 0 or len(B.centres) == 0:
            return np.zeros((0, 2), np.int32)
        D = scaled_distance(own.vehicle_features, other.vehicle_features, descriptor_scale)
        pairs, _ = _assign(A, B, D, R, t, cfg, None, _scores(own, cfg), _scores(other, cfg), dist)
        return pairs

    def score(self, own: SharedFrame, other: SharedFrame, R: np.ndarray, t: np.ndarray,
              descriptor_scale: float = 1.0) -> np.ndarray:
        """(H,) this matcher's evidence for hypotheses R (H, 2, 2), t (H, 2) of the other -> own
        transform: vehicle consensus plus weighted background agreement (no track prior)."""
        return self.scorer(own, other, descriptor_scale)(R, t)

    def scorer(self, own: SharedFrame, other: SharedFrame, descriptor_scale: float = 1.0):
        """`score` for one frame pair with its per-frame work done once: a callable (R, t) -> (H,)."""
        cfg = self.cfg
        A, B = observe(own, cfg.observation), observe(other, cfg.observation)
        bg_own, bg_other = own.background[:, :2], other.background[:, :2]
        tree = background_tree(own)
        alike_of = None
        offsets = sighting_offsets(own, other, cfg.sighting)
        yaws = heading_yaws(own, other)
        allow = crossing_allowance(own, other, cfg.cross_band_deg)
        off_grid = functools.partial(_off_grid, yaws=yaws, allowance=allow, cfg=cfg)
        if len(A.centres) and len(B.centres):
            D = scaled_distance(own.vehicle_features, other.vehicle_features, descriptor_scale)
            alike_of = _likeness(D, yaws, road_speed_consistency(own, other), cfg,
                                 _confidence(own, cfg), _confidence(other, cfg), allowance=allow)

        def of(R: np.ndarray, t: np.ndarray) -> np.ndarray:
            if len(R) == 0:
                return np.zeros(0)
            bg = cfg.background_weight * _background_scores(bg_own, bg_other, R, t, cfg, tree) \
                - cfg.off_grid_penalty * off_grid(R)
            return bg if alike_of is None else _vehicle_scores(A, B, alike_of(R), R, t, cfg, offsets) + bg
        return of


def _prior_agreement(R: np.ndarray, t: np.ndarray, prior: np.ndarray, cfg: ConsensusConfig) -> np.ndarray:
    """(H,) 0-1 closeness of each hypothesis to the track's prediction."""
    d = np.linalg.norm(t - prior[:2, 3], axis=1)
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0]) - np.arctan2(prior[1, 0], prior[0, 0])
    dy = np.abs((yaw + np.pi) % (2 * np.pi) - np.pi)
    return np.exp(-0.5 * ((d / cfg.prior_sigma_m) ** 2 + (dy / np.radians(cfg.prior_sigma_deg)) ** 2))


def _yaw_gap(R: np.ndarray, yaws: np.ndarray, per_candidate: bool = False,
             allowance: np.ndarray | None = None) -> np.ndarray:
    """Angular distance (rad) of each hypothesis' yaw to the prior yaws: (H,) nearest, or (H, 4);
    allowance: (4,) rad taken off each candidate's distance (base.crossing_allowance)."""
    gap = np.abs((np.arctan2(R[:, 1, 0], R[:, 0, 0])[:, None] - yaws + np.pi) % (2 * np.pi) - np.pi)
    if allowance is not None:
        gap = np.maximum(gap - allowance, 0.0)
    return gap if per_candidate else gap.min(axis=1)


def _off_grid(R: np.ndarray, yaws: np.ndarray | None, allowance: np.ndarray | None,
              cfg: ConsensusConfig) -> np.ndarray:
    """(H,) 0-1 how far each hypothesis lies off every heading yaw: 0 within the yaw gate, 1 from
    cfg.off_grid_full_deg on; 0 everywhere without a crossing allowance (ConsensusConfig)."""
    if yaws is None or allowance is None or len(R) == 0:
        return np.zeros(len(R))
    gap = np.degrees(_yaw_gap(R, yaws))
    span = max(cfg.off_grid_full_deg - cfg.yaw_gate_deg, 1e-9)
    return np.clip((gap - cfg.yaw_gate_deg) / span, 0.0, 1.0)


def _scores(frame: SharedFrame, cfg: ConsensusConfig) -> np.ndarray:
    """(V,) the frame's detection scores lifted to a median of at least `typical_score`
    (base.detection_scores)."""
    return detection_scores(frame, cfg.typical_score)


def _confidence(frame: SharedFrame, cfg: ConsensusConfig) -> np.ndarray:
    """(V,) 0-1 trust in each vehicle from its detection score (false detections score low)."""
    c = (_scores(frame, cfg) - cfg.score_low) / (cfg.score_high - cfg.score_low)
    return np.clip(c, cfg.min_confidence, 1.0)


def _nearest_heading(R: np.ndarray, yaws: np.ndarray, allowance: np.ndarray | None,
                     cfg: ConsensusConfig) -> tuple[np.ndarray, np.ndarray]:
    """(H,) each hypothesis' nearest heading yaw (index into yaws) and (H,) whether it lies off
    every one (beyond the yaw gate: `_off_grid` > 0), from one table of gaps; never off without a
    crossing allowance."""
    gap = _yaw_gap(R, yaws, per_candidate=True)
    if allowance is None:
        return gap.argmin(axis=1), np.zeros(len(R), bool)
    return gap.argmin(axis=1), np.degrees(gap.min(axis=1)) > cfg.yaw_gate_deg


def _likeness(D, yaws, speed, cfg, conf_a, conf_b, P=None, allowance=None):
    """A function of hypotheses R (H, 2, 2) -> (H or 1, Va, Vb) likeness of each pair.

    P: (Va, Vb) network pair scores (0-1) or None; with them the appearance likeness takes
    1 - cfg.pair_score_share of the weight and 2 P - 0.5 (the same -0.5 ... 1.5 range) the rest.
    With road speeds a hypothesis's likeness depends on it only through its nearest heading
    yaw: the (4, Va, Vb) likeness of each yaw is computed once and each hypothesis takes its own;
    one off every heading yaw (`_nearest_heading`, with the crossing allowance: an oblique
    crossing) takes none, for the road speeds assume right angles."""
    if cfg.desc_width > 0:   # likelihood-shaped: about 2 when clearly alike, 0 when clearly not
        alike = (2.0 / (1.0 + np.exp((D - cfg.desc_mid) / cfg.desc_width)) - 0.5)[None]
    else:
        alike = np.clip(1 - D / cfg.desc_gate, 0, None)[None]
    if P is not None:
        alike = (1.0 - cfg.pair_score_share) * alike + cfg.pair_score_share * (2.0 * P - 0.5)[None]
    conf = np.sqrt(conf_a[:, None] * conf_b[None, :])[None]
    same = (0.5 + alike) * conf - 0.5
    if speed is None or yaws is None:
        return lambda R: same
    per_yaw = (0.5 + (alike + cfg.speed_weight * speed)) * conf - 0.5           # (4, Va, Vb)

    def of(R: np.ndarray) -> np.ndarray:
        nearest, off = _nearest_heading(R, yaws, allowance, cfg)
        out = per_yaw[nearest]
        if off.any():
            out[off] = same[0]
        return out
    return of


def _rotations(yaws: np.ndarray) -> np.ndarray:
    """(Y, 2, 2) planar rotation matrices of yaws (Y,) rad."""
    c, s = np.cos(yaws), np.sin(yaws)
    R = np.empty((len(c), 2, 2))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = c, -s, s, c
    return R


def _pairs_of(n: int) -> tuple[np.ndarray, np.ndarray]:
    """np.triu_indices(n, 1): every two of n items (i < j); kept for up to 64 items
    (read-only), where building them costs more than using them."""
    return _small_pairs_of(n) if n <= 64 else np.triu_indices(n, 1)


@functools.lru_cache(maxsize=65)
def _small_pairs_of(n: int) -> tuple[np.ndarray, np.ndarray]:
    p, q = np.triu_indices(n, 1)
    p.flags.writeable = q.flags.writeable = False
    return p, q


def _single_pair_hypotheses(A, B, cand, yaws):
    """Transforms from one candidate pair placed under each heading-prior yaw: (C*4, 2, 2), (C*4, 2)."""
    Rk = _rotations(yaws)                                                   # (4, 2, 2)
    R = np.repeat(Rk[None], len(cand), 0).reshape(-1, 2, 2)
    Bj = np.repeat(B[cand[:, 1]], len(yaws), 0)
    t = np.repeat(A[cand[:, 0]], len(yaws), 0) - (R @ Bj[:, :, None])[..., 0]
    return R, t


def best_first(rank: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Hypothesis indices by rank (H,), highest first; equal ranks (sighting hypotheses often
    tie) by where they put the other radar, t (H, 2), so that the order of the detections, which
    orders the hypotheses, cannot choose among them."""
    return np.lexsort((t[:, 1], t[:, 0], -rank))


def _sighting_hypotheses(A, B, yaws, off_a, off_b):
    """Transforms that put the other vehicle on one own detection, or the own vehicle on one of the
    other's, under each heading-prior yaw: (4 (Va + Vb), 2, 2), (4 (Va + Vb), 2).

    A radar sits off_a[k] (off_b[m]) ahead of detection A[k]'s (B[m]'s) centre along that
    vehicle's heading (y forward; `SightingModel.offsets`): other -> own maps the other's
    body centre (0, -off_a[k]) onto own detection A[k]; the own body centre (0, -off_b[m]) onto
    B[m] is R B[m] + t = (0, -off_b[m])."""
    Rk = _rotations(yaws)                                                   # (Y, 2, 2)
    t_a = A[:, None] + off_a[:, None, None] * Rk[None, :, :, 1]                # (Va, Y, 2)
    body_b = np.column_stack([np.zeros(len(B)), -off_b])
    t_b = body_b[:, None] - (B @ Rk.transpose(0, 2, 1)).transpose(1, 0, 2)    # (Vb, Y, 2)
    t = np.concatenate([t_a.reshape(-1, 2), t_b.reshape(-1, 2)])
    R = np.tile(Rk, (len(A) + len(B), 1, 1))
    return R, t


def _distinct_best(R, t, score, cfg, n):
    """Indices of the best n hypotheses, skipping near-duplicates of better ones."""
    return distinct_best(R, t, np.argsort(-score), n, cfg.distinct_m, cfg.distinct_deg)


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


def _most_alike(cost: np.ndarray, n: int) -> np.ndarray:
    """Indices of the n least `cost` entries, in their original order."""
    return np.sort(np.argsort(cost, kind="stable")[:n])


def _pair_hypotheses(A, B, cand, cfg, cost, most):
    """Transforms (H, 2, 2), (H, 2) from every two compatible candidate pairs; with more than
    `most`, those whose two pairs have the least summed `cost` (C,) (the descriptor distance),
    in their original order."""
    if len(cand) < 2:
        if len(cand) == 1:   # one pair: identity rotation placed on it (a weak hypothesis)
            i, j = cand[0]
            return np.eye(2)[None], (A[i] - B[j])[None]
        return np.zeros((0, 2, 2)), np.zeros((0, 2))
    p, q = _pairs_of(len(cand))
    i, j, k, l = cand[p, 0], cand[p, 1], cand[q, 0], cand[q, 1]
    ok = (i != k) & (j != l)
    da = lengths(A[i] - A[k])
    db = lengths(B[j] - B[l])
    ok &= (np.abs(da - db) < cfg.pair_dist_tol_m + cfg.pair_dist_tol_rel * da) & (da > cfg.min_baseline_m)
    i, j, k, l = i[ok], j[ok], k[ok], l[ok]
    if len(i) > most:
        keep = _most_alike(cost[p[ok]] + cost[q[ok]], most)
        i, j, k, l = i[keep], j[keep], k[keep], l[keep]
    va, vb = A[k] - A[i], B[l] - B[j]
    R = _rotations(np.arctan2(va[:, 1], va[:, 0]) - np.arctan2(vb[:, 1], vb[:, 0]))
    mid_a, mid_b = (A[i] + A[k]) / 2, (B[j] + B[l]) / 2
    t = mid_a - (R @ mid_b[:, :, None])[..., 0]
    return R, t


def _in_view(p: np.ndarray, cfg: ConsensusConfig) -> np.ndarray:
    """Whether points (..., 2) in a radar frame lie where that vehicle's camera detects vehicles."""
    r = lengths(p)
    az = np.abs(np.arctan2(p[..., 0], p[..., 1]))
    return (r > 4.0) & (r < cfg.camera_range_m) & (az < np.radians(cfg.camera_half_fov_deg))


def _vehicle_scores(A: Observations, B: Observations, alike, R, t, cfg, offsets=None):
    """(H,) evidence for each hypothesis from the vehicles alone.

    + each own vehicle landing near a look-alike other vehicle (closeness in Mahalanobis
      units x likeness);
    - each vehicle the other camera should have seen, unmatched (misses cost less than
      wrong matches: occlusion hides some);
    + the other vehicle itself among the detections where the hypothesis puts it.

    offsets: (Va,), (Vb,) `sighting_offsets` (None: every detection at the car's).
    """
    out = np.empty(len(R))
    for lo in range(0, len(R), 512):                                  # bounded memory
        sl = slice(lo, lo + 512)
        out[sl] = _vehicle_scores_chunk(A, B, alike if len(alike) == 1 else alike[sl], R[sl], t[sl], cfg,
                                        offsets)
    return out


def _vehicle_scores_chunk(A, B, alike, R, t, cfg, offsets=None):
    """`_vehicle_scores` of up to 512 hypotheses. The distances and their reductions have the
    hypotheses last (numpy reduces short last axes slowly); each hypothesis's closeness is
    summed over a (H, Va) array, as it always was."""
    dist = pair_major_mahalanobis(A, B, R, t)                          # (Va, Vb, H)
    close = dist / cfg.gate_sigma                                      # 1 - dist / gate, at least 0
    np.subtract(1, close, out=close)
    np.maximum(close, 0, out=close)
    weight = np.clip(0.5 + alike, 0, None)                             # (H or 1, Va, Vb)
    best = (close * np.ascontiguousarray(weight.transpose(1, 2, 0))).max(axis=1)       # (Va, H)
    score = np.ascontiguousarray(best.T).sum(axis=1)
    Va = len(A.centres)
    Ac, Bc = A.centres, B.centres
    Bt = Bc @ R.transpose(0, 2, 1) + t[:, None]                        # (H, Vb, 2) other vehicles, own frame
    body = np.array([0.0, -cfg.sighting.body_offset_m])
    cav_body = R @ body + t                                            # (H, 2) other vehicle's centre, own frame
    A_in_cav = (Ac[None] - t[:, None]) @ R                             # (H, Va, 2) own vehicles, other frame
    ego_body_in_cav = ((body[None] - t)[:, None] @ R)[:, 0]            # (H, 2)
    if offsets is None:
        offsets = (np.full(Va, -body[1]), np.full(len(Bc), -body[1]))
    # the sightings of both views, (H, Va + Vb): a vehicle where it puts the other radar; and
    # where each camera looks, each in one call for both
    sighted = lengths(np.concatenate(sighting_gaps(R, t, Ac, Bc, offsets), axis=1)) < cfg.sighting_m
    a_is_cav, b_is_ego = sighted[:, :Va], sighted[:, Va:]
    places = np.concatenate([A_in_cav, Bt, cav_body[:, None], ego_body_in_cav[:, None]], axis=1)
    view = _in_view(places, cfg)                                       # (H, Va + Vb + 2)
    unpaired = (np.concatenate([dist.min(axis=1), dist.min(axis=0)]) > cfg.gate_sigma).T
    miss = (unpaired & view[:, :-2] & ~sighted).sum(1)
    seen = a_is_cav.any(1).astype(float) * view[:, -2] + b_is_ego.any(1).astype(float) * view[:, -1]
    return score - cfg.miss_weight * miss + cfg.sighting_weight * seen


def _background_scores(bg_own, bg_other, R, t, cfg, tree=None):
    """(H,) share of the other view's background (N, 2) landing within the gate of the own."""
    if len(bg_own) < 3 or len(bg_other) < 3:
        return np.zeros(len(R))
    src = bg_other
    if len(src) > cfg.background_points:
        src = src[_background_sample(len(src), cfg.background_points)]
    tree = tree or cKDTree(bg_own)
    moved = src @ R.transpose(0, 2, 1) + t[:, None]
    d, _ = tree.query(moved.reshape(-1, 2), distance_upper_bound=cfg.background_gate_m)
    d = d.reshape(len(R), -1)
    hit = np.exp(-0.5 * (d / cfg.background_sigma_m) ** 2) if cfg.background_sigma_m > 0 else np.isfinite(d)
    if not cfg.background_in_view:
        return hit.mean(axis=1)
    r = np.linalg.norm(moved, axis=2)
    seen = (np.abs(np.arctan2(moved[..., 0], moved[..., 1])) < np.radians(cfg.radar_half_fov_deg)) \
        & (r < cfg.radar_range_m)
    return (hit * seen).sum(axis=1) / np.maximum(seen.sum(axis=1), cfg.background_min_seen)


@functools.lru_cache(maxsize=256)
def _background_sample(n: int, k: int) -> np.ndarray:
    """The k of n background points `_background_scores` uses: a fixed draw (seed 0) that
    depends on n alone, so kept per n (read-only; the draw costs 100 us)."""
    idx = np.random.default_rng(0).choice(n, k, replace=False)
    idx.flags.writeable = False
    return idx


def _assign(A: Observations, B: Observations, D, R, t, cfg, veto=None, score_a=None, score_b=None, dist=None):
    """One-to-one pairs under a transform: Hungarian on Mahalanobis distance + appearance, gated (and vetoed).

    A detection scoring (normalised, see `_scores`) below assign_min_score is never matched.
    dist: the (Va, Vb) distances under R, t when at hand.
    """
    if dist is None:
        dist = mahalanobis(A, B, R[None], t[None])[0]
    cost = dist / cfg.assign_gate_sigma + cfg.desc_weight * D
    big = 1e6
    allowed = (dist < cfg.assign_gate_sigma) & (D < cfg.desc_gate)
    if score_a is not None and score_b is not None:
        allowed &= np.minimum(score_a[:, None], score_b[None, :]) >= cfg.assign_min_score
    if veto is not None:
        allowed &= ~veto
    gated = np.where(allowed, cost, big)
    r, c = linear_sum_assignment(gated)
    ok = gated[r, c] < big
    pairs = np.column_stack([r[ok], c[ok]]).astype(np.int32)
    return pairs, cost[r[ok], c[ok]] / (1 + cfg.desc_weight)
