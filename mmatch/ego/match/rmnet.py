"""The `rmnet` matcher: RM-net proposes co-visible pairs, geometry verifies them.

1. RM-net (graph.py, run by ONNX Runtime) scores every own x other vehicle pair (0-1).
2. Pruning: each vehicle keeps its `top_k` best-scoring partners (either side), above
   `min_prob`; these candidate pairs are all the geometry looks at.
3. Hypotheses of the planar other -> own transform: each of the `seeds` best candidates
   with every other compatible candidate (inter-vehicle distances agree), and each seed
   alone under each yaw the two radars' velocities allow. That is seeds x C ~ V x V
   hypotheses, not C^2 ~ V^4 as without the network.
4. Coarse verification: each hypothesis scores the candidates it explains (Mahalanobis
   distance of the two views' line-of-sight ellipses, weighted by the network's score); the
   best distinct ones are refined (Gauss-Newton on vehicles, background and heading,
   refine.py) and rescored with the `consensus` matcher's evidence (vehicles where the
   hypothesis puts them, misses, mutual sighting, background overlap), the network's score
   standing in for appearance likeness.
5. Pairs: one-to-one (Hungarian) under the best transform, gated in Mahalanobis distance
   and network score; they and the transform (T_hint) go on to alignment.

A time budget (`budget_ms`, default 30 ms) bounds every frame's work: past it the matcher
returns the best transform verified so far (coarse if refinement did not start), or "no
estimate" (no pairs, no transform) when nothing was verified yet. The budget counts the
CPU time of the matching thread (`time.thread_time`), so what a frame may do does not
change with how busy the computer is (a loaded machine stretches the wall time of the same
work). A view with fewer than two vehicles gives no pairs.

Other matchers built from the same parts for the ablation: `rmnet-only` (the network's
mutual best pairs, no geometry), `geometry` (the same verification with every pair a
candidate and no appearance), `descriptor` (Hungarian on descriptor distance alone).
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from mmatch.ego.base import (Hypotheses, MatchContext, MatchResult, background_tree,
                             crossing_allowance, heading_yaws, road_speed_consistency,
                             sighting_offsets)
from mmatch.ego.descriptor_scale import scaled_distance
from mmatch.ego.match import consensus as cs
from mmatch.ego.match.graph import build_graph
from mmatch.ego.match.rmnet_runtime import RMNetSession
from mmatch.ego.memo import memo
from mmatch.ego.observations import Observations, mahalanobis, observe
from mmatch.ego.refine import refine_many
from mmatch.ego.rigid import se2_to_matrix
from mmatch.shared import SharedFrame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RMNetConfig:
    """Pruning, verification and budget of the `rmnet` matcher.

    model_path: the ONNX file (None: the one shipped in mmatch/models).
    """

    model_path: str | None = None
    top_k: int = 2                      # partners kept per vehicle (each side); 3 before the retrained
                                        # network (top-3 recall 1.000): same results on 1500 scenes,
                                        # dense Ego path 19.7 -> 17.3 ms median (README)
    min_prob: float = 0.02              # candidate pairs score at least this
    desc_candidates: int = 2            # also keep each vehicle's best look-alikes by descriptor (0: none)
    desc_candidate_weight: float = 0.5  # their weight: this times the descriptor likeness (0-1), if above p
    seeds: int = 16                     # best candidates that seed two-pair hypotheses
    max_hypotheses: int = 1200          # coarse hypotheses kept (by the product of their seeds' scores)
    coarse_gate_sigma: float = 3.0      # a candidate pair is explained within this Mahalanobis distance
    refine_hypotheses: int = 6          # best distinct coarse hypotheses refined and rescored ...
    refine_pair_budget: int = 2400      # ... fewer in dense traffic: at most this / (Va x Vb), at least 2
    min_support: float = 0.5            # coarse evidence (explained score mass) a transform needs
    prob_likeness: float = 2.0          # network score -> likeness (consensus units): 2 p - 0.5
    desc_share: float = 0.0             # share of the consensus descriptor likeness in the likeness
    assign_desc_weight: float = 0.0     # weight of the descriptor distance in the assignment cost
    assign_gate_sigma: float = 2.5
    assign_min_prob: float = 0.05       # pairs the network scores below this are never matched
    assign_prob_weight: float = 1.0     # weight of (1 - p) in the assignment cost
    assign_alike_desc: float = 0.15     # > 0: a pair this alike by descriptor passes the score gate too
    budget_ms: float = 30.0             # CPU ms per frame; past it: best verified answer so far
    consensus: cs.ConsensusConfig = field(default_factory=cs.ConsensusConfig)


class RMNetMatcher:
    name = "rmnet"
    pairs_from_transform = True     # the fused pairs are those the published transform implies (fusion.py)
    pairs_by_rmnet = True           # pairs_under is its own assignment, the one the confidence evidence makes

    def __init__(self, config: RMNetConfig = RMNetConfig(), session: RMNetSession | None = None) -> None:
        self.cfg = config
        self.session = session if session is not None else RMNetSession(config.model_path)

    def probabilities(self, own: SharedFrame, other: SharedFrame) -> tuple[np.ndarray, Observations, Observations]:
        """(Va, Vb) network scores and both views' observations; zeros below two vehicles a view.
        Once per frame pair inside a fusion (ego/memo.py)."""
        return memo("rmnet_probabilities", (own, other, self.session), lambda: self._probabilities(own, other))

    def _probabilities(self, own: SharedFrame, other: SharedFrame) -> tuple[np.ndarray, Observations, Observations]:
        if own.num_vehicles < 2 or other.num_vehicles < 2:
            return np.zeros((own.num_vehicles, other.num_vehicles)), observe(own), observe(other)
        g = build_graph(own, other)
        return self.session.run_graph(g).astype(np.float64), g.obs_own, g.obs_other

    def pairs_under(self, own: SharedFrame, other: SharedFrame, R: np.ndarray, t: np.ndarray,
                    descriptor_scale: float = 1.0, observed: tuple | None = None) -> np.ndarray:
        """(P, 2) the one-to-one pairs this matcher assigns under one transform R (2, 2), t (2,):
        its final assignment (distance, network score, detection score) without the road-speed veto.

        observed: the two frames' Observations when already at hand."""
        return self.pairs_under_many(own, other, np.asarray(R)[None], np.asarray(t)[None], descriptor_scale,
                                     observed)[0]

    def pairs_under_many(self, own: SharedFrame, other: SharedFrame, R: np.ndarray, t: np.ndarray,
                         descriptor_scale: float = 1.0, observed: tuple | None = None,
                         dist: np.ndarray | None = None) -> list[np.ndarray]:
        """`pairs_under` for H transforms R (H, 2, 2), t (H, 2) at once: H (P, 2) arrays (one
        distance computation for all, one assignment each). dist: the (H, Va, Vb) Mahalanobis
        distances of the observed vehicles under R, t when at hand."""
        P, A, B = self.probabilities(own, other)
        if observed is not None:
            A, B = observed
        if len(A.centres) == 0 or len(B.centres) == 0:
            return [np.zeros((0, 2), np.int32) for _ in range(len(R))]
        ccfg = self.cfg.consensus
        D = scaled_distance(own.vehicle_features, other.vehicle_features, descriptor_scale)
        if dist is None:
            dist = mahalanobis(A, B, np.asarray(R, float), np.asarray(t, float))
        gated = _gated_cost(P, dist, self.cfg, None, cs._scores(own, ccfg), cs._scores(other, ccfg), D)
        return [_one_to_one(g, P)[0] for g in gated]

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        t0 = time.thread_time()
        if own.num_vehicles < 2 or other.num_vehicles < 2:
            return MatchResult()
        P, A, B = self.probabilities(own, other)
        return verify(own, other, ctx, P, A, B, self.cfg, t0)


def verify(own: SharedFrame, other: SharedFrame, ctx: MatchContext, P: np.ndarray, A: Observations,
           B: Observations, cfg: RMNetConfig, t0: float, candidates: np.ndarray | None = None,
           use_appearance: bool = True) -> MatchResult:
    """Steps 2-5 of the module docstring on pair scores P (Va, Vb); t0: the frame's start (thread_time s).

    candidates: (C, 2) pairs to use instead of the top-k pruning; use_appearance False leaves
    descriptors out of refinement and scoring (the `geometry` ablation).
    """
    deadline = t0 + cfg.budget_ms / 1e3
    ccfg = cfg.consensus
    scale = 1.0 if ctx.descriptor_scale is None else ctx.descriptor_scale
    D = scaled_distance(own.vehicle_features, other.vehicle_features, scale) if use_appearance \
        else np.zeros(P.shape)
    W = P
    if candidates is None and cfg.desc_candidates > 0:
        like = 1.0 / (1.0 + np.exp((D - ccfg.desc_mid) / ccfg.desc_width))
        W = np.maximum(P, cfg.desc_candidate_weight * like * (D < ccfg.desc_gate))
        cand = np.unique(np.concatenate([prune(P, cfg.top_k, cfg.min_prob),
                                         prune(-D, cfg.desc_candidates, -ccfg.desc_gate)]), axis=0)
    else:
        cand = prune(P, cfg.top_k, cfg.min_prob) if candidates is None else candidates
    w = W[cand[:, 0], cand[:, 1]] if len(cand) else np.zeros(0)
    yaws = heading_yaws(own, other)
    allow = crossing_allowance(own, other, ccfg.cross_band_deg)
    off_grid = functools.partial(cs._off_grid, yaws=yaws, allowance=allow, cfg=ccfg)
    prior = ctx.prior_T
    if prior is not None and ctx.prior_only:
        R, t = prior[None, :2, :2], prior[None, :2, 3]
    else:
        R, t = hypotheses(A.centres, B.centres, cand, w, yaws, cfg, allow)
        if prior is not None:
            R, t = np.concatenate([R, prior[None, :2, :2]]), np.concatenate([t, prior[None, :2, 3]])
    if len(R) == 0 or len(cand) == 0 and prior is None:
        return MatchResult(descriptor_scale=scale)
    coarse = coarse_scores(A, B, cand, w, R, t, cfg.coarse_gate_sigma)
    if prior is not None:
        coarse[-1] = np.inf                               # the track's prediction is always refined
    speed = road_speed_consistency(own, other)
    alike_of = _likeness(P, D, yaws, speed, cfg, use_appearance, allow)
    best = int(np.argmax(coarse))
    if coarse[best] < cfg.min_support:
        return MatchResult(descriptor_scale=scale)
    R_b, t_b = R[best], t[best]
    hyps = None
    if time.thread_time() < deadline:
        n_refine = ccfg.refine_with_prior if prior is not None else \
            max(2, min(cfg.refine_hypotheses, cfg.refine_pair_budget // max(P.size, 1)))
        top = cs._distinct_best(R, t, coarse, ccfg, n_refine)
        bg_own, bg_other = own.background[:, :2], other.background[:, :2]
        tree = background_tree(own)
        rcfg = ccfg.tracking_refine() if ctx.prior_only and prior is not None else ccfg.refine
        allowed = W >= cfg.min_prob if candidates is None else None
        R_ref, t_ref = refine_many(A, B, D, bg_own, bg_other, R[top], t[top], yaws, rcfg, tree, allowed)
        if time.thread_time() < deadline:
            Rr, tr = np.concatenate([R[top], R_ref]), np.concatenate([t[top], t_ref])
            offsets = sighting_offsets(own, other, ccfg.sighting)
            total = cs._vehicle_scores(A, B, alike_of(Rr), Rr, tr, ccfg, offsets) \
                + ccfg.background_weight * cs._background_scores(bg_own, bg_other, Rr, tr, ccfg,
                                                                 tree) \
                - ccfg.off_grid_penalty * off_grid(Rr)
            if prior is not None and ccfg.prior_weight:
                total = total + ccfg.prior_weight * cs._prior_agreement(Rr, tr, prior, ccfg)
            k = int(np.argmax(total))
            R_b, t_b = Rr[k], tr[k]
            hyps = Hypotheses(Rr, tr, total)
        else:
            R_b, t_b = R_ref[0], t_ref[0]                 # the best coarse hypothesis, refined
    veto = None
    if speed is not None and yaws is not None:
        nearest, off = cs._nearest_heading(R_b[None], yaws, allow, ccfg)
        veto = None if off[0] else speed[nearest[0]] < 0
    pairs, score = assign(A, B, P, R_b, t_b, cfg, veto, cs._scores(own, ccfg), cs._scores(other, ccfg), D)
    T = se2_to_matrix(R_b, t_b, other.radar_height - own.radar_height)
    return MatchResult(pairs=pairs, scores=score, T_hint=T, descriptor_scale=scale, hypotheses=hyps)


def prune(P: np.ndarray, k: int, min_prob: float) -> np.ndarray:
    """(C, 2) candidate pairs: each vehicle's top-k partners by score (own rows or other columns), >= min_prob."""
    Va, Vb = P.shape
    if Va == 0 or Vb == 0:
        return np.zeros((0, 2), int)
    keep = np.zeros(P.shape, bool)
    kr, kc = min(k, Vb), min(k, Va)
    rows = np.argpartition(-P, kr - 1, axis=1)[:, :kr]
    keep[np.repeat(np.arange(Va), kr), rows.ravel()] = True
    cols = np.argpartition(-P, kc - 1, axis=0)[:kc, :]
    keep[cols.ravel(), np.tile(np.arange(Vb), kc)] = True
    keep &= P >= min_prob
    return np.argwhere(keep)


def _rot(ang: np.ndarray) -> np.ndarray:
    c, s = np.cos(ang), np.sin(ang)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def hypotheses(A: np.ndarray, B: np.ndarray, cand: np.ndarray, w: np.ndarray, yaws: np.ndarray | None,
               cfg: RMNetConfig, allowance: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Transforms (H, 2, 2), (H, 2) from the seeds paired with every compatible candidate, and the seeds under the yaws.

    A (Va, 2), B (Vb, 2) vehicle centres; cand (C, 2) candidate pairs with scores w (C,);
    allowance: the yaw gate's crossing allowance (base.crossing_allowance).
    """
    ccfg = cfg.consensus
    if len(cand) == 0:
        return np.zeros((0, 2, 2)), np.zeros((0, 2))
    order = np.argsort(-w, kind="stable")
    seeds = order[: cfg.seeds]
    s, c = np.repeat(seeds, len(cand)), np.tile(np.arange(len(cand)), len(seeds))
    i, j, k, l = cand[s, 0], cand[s, 1], cand[c, 0], cand[c, 1]
    da = np.linalg.norm(A[i] - A[k], axis=1)
    db = np.linalg.norm(B[j] - B[l], axis=1)
    ok = (i != k) & (j != l) & (da > ccfg.min_baseline_m) \
        & (np.abs(da - db) < ccfg.pair_dist_tol_m + ccfg.pair_dist_tol_rel * da)
    # a seed pairs with a later seed only once
    rank = np.empty(len(cand), int)
    rank[order] = np.arange(len(cand))
    ok &= ~((rank[c] < cfg.seeds) & (rank[c] < rank[s]))
    s, c, i, j, k, l = s[ok], c[ok], i[ok], j[ok], k[ok], l[ok]
    if len(s) > cfg.max_hypotheses:
        best = np.argsort(-(w[s] * w[c]), kind="stable")[: cfg.max_hypotheses]
        s, c, i, j, k, l = s[best], c[best], i[best], j[best], k[best], l[best]
    va, vb = A[k] - A[i], B[l] - B[j]
    R = _rot(np.arctan2(va[:, 1], va[:, 0]) - np.arctan2(vb[:, 1], vb[:, 0]))
    t = (A[i] + A[k]) / 2 - np.einsum("hij,hj->hi", R, (B[j] + B[l]) / 2)
    if yaws is not None:
        Rk = _rot(np.asarray(yaws))                                          # (4, 2, 2)
        R1 = np.repeat(Rk[None], len(seeds), 0).reshape(-1, 2, 2)
        Bj = np.repeat(B[cand[seeds, 1]], len(yaws), 0)
        t1 = np.repeat(A[cand[seeds, 0]], len(yaws), 0) - np.einsum("hij,hj->hi", R1, Bj)
        R, t = np.concatenate([R, R1]), np.concatenate([t, t1])
        keep = cs._yaw_gap(R, yaws, allowance=allowance) < np.radians(ccfg.yaw_gate_deg)
        if keep.any():
            R, t = R[keep], t[keep]
    return R, t


def pair_mahalanobis(A: Observations, B: Observations, cand: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(H, C) Mahalanobis distance of each candidate pair (own i, other j) under each hypothesis
    (best estimates), in float32 as observations._maha_sq."""
    f = np.float32
    ca, Sa = A.centres[cand[:, 0]].astype(f), A.cov[cand[:, 0]].astype(f)
    cb, Sb = B.centres[cand[:, 1]].astype(f), B.cov[cand[:, 1]].astype(f)
    R, t = np.asarray(R, f), np.asarray(t, f)
    c, s = R[:, 0, 0][:, None], R[:, 1, 0][:, None]                            # (H, 1)
    bx, by = cb[None, :, 0], cb[None, :, 1]
    dx = ca[None, :, 0] - (c * bx - s * by + t[:, 0:1])
    dy = ca[None, :, 1] - (s * bx + c * by + t[:, 1:2])
    a, b, d = Sb[None, :, 0, 0], Sb[None, :, 0, 1], Sb[None, :, 1, 1]
    cc, ss, csn = c * c, s * s, c * s
    s00 = Sa[None, :, 0, 0] + a * cc - 2 * b * csn + d * ss
    s01 = Sa[None, :, 0, 1] + (a - d) * csn + b * (cc - ss)
    s11 = Sa[None, :, 1, 1] + a * ss + 2 * b * csn + d * cc
    det = np.maximum(s00 * s11 - s01 * s01, f(1e-12))
    return np.sqrt(np.maximum((s11 * dx * dx - 2 * s01 * dx * dy + s00 * dy * dy) / det, f(0.0)))


def coarse_scores(A: Observations, B: Observations, cand: np.ndarray, w: np.ndarray, R: np.ndarray,
                  t: np.ndarray, gate: float) -> np.ndarray:
    """(H,) score mass of the candidates each hypothesis explains: sum w * max(0, 1 - d / gate)."""
    out = np.zeros(len(R))
    if len(cand) == 0:
        return out
    # about 16k hypothesis x candidate entries a chunk: each of the dozen (H, C) float32 arrays of
    # `pair_mahalanobis` stays in cache (458 hypotheses x 150 candidates: 2.05 -> 1.35 ms against
    # chunks of 1024 hypotheses; every row is computed alone, so the scores are the same)
    step = max(16, 16384 // len(cand))
    for lo in range(0, len(R), step):
        d = pair_mahalanobis(A, B, cand, R[lo:lo + step], t[lo:lo + step])
        out[lo:lo + step] = (np.clip(1 - d / gate, 0, None) * w[None]).sum(axis=1)
    return out


def _likeness(P: np.ndarray, D: np.ndarray, yaws, speed, cfg: RMNetConfig, use_appearance: bool,
              allowance: np.ndarray | None = None):
    """A function of hypotheses R (H, 2, 2) -> (H or 1, Va, Vb) likeness of each pair (consensus
    units); hypotheses off every heading yaw (`consensus._nearest_heading` with the crossing
    allowance) weigh no road speeds."""
    ccfg = cfg.consensus
    if use_appearance:
        net = cfg.prob_likeness * P - 0.5
        desc = 2.0 / (1.0 + np.exp((D - ccfg.desc_mid) / ccfg.desc_width)) - 0.5
        base = ((1 - cfg.desc_share) * net + cfg.desc_share * desc)[None]
    else:
        base = np.full((1,) + P.shape, 0.5)

    def of(R: np.ndarray) -> np.ndarray:
        if speed is None or yaws is None:
            return base
        nearest, off = cs._nearest_heading(R, yaws, allowance, ccfg)
        out = base + ccfg.speed_weight * speed[nearest]
        if off.any():
            out[off] = base[0]
        return out
    return of


def assign(A: Observations, B: Observations, P: np.ndarray, R: np.ndarray, t: np.ndarray, cfg: RMNetConfig,
           veto: np.ndarray | None = None, score_a: np.ndarray | None = None,
           score_b: np.ndarray | None = None, D: np.ndarray | None = None,
           dist: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs under a transform: Hungarian on Mahalanobis distance + (1 - network score)
    (+ descriptor distance D), gated. dist: the (Va, Vb) distances under R, t when at hand."""
    if dist is None:
        dist = mahalanobis(A, B, R[None], t[None])[0]
    return _one_to_one(_gated_cost(P, dist, cfg, veto, score_a, score_b, D), P)


_NOT_ALLOWED = 1e6      # the cost of a pair `assign` may not make


def _gated_cost(P: np.ndarray, dist: np.ndarray, cfg: RMNetConfig, veto: np.ndarray | None,
                score_a: np.ndarray | None, score_b: np.ndarray | None, D: np.ndarray | None) -> np.ndarray:
    """`assign`'s cost of each pair, _NOT_ALLOWED where a gate refuses it: (..., Va, Vb) of the
    distances dist (..., Va, Vb) under one transform or each of several."""
    cost = dist / cfg.assign_gate_sigma + cfg.assign_prob_weight * (1 - P)
    if D is not None and cfg.assign_desc_weight > 0:
        cost = cost + cfg.assign_desc_weight * D
    allowed = P >= cfg.assign_min_prob
    if D is not None and cfg.assign_alike_desc > 0:
        allowed |= D < cfg.assign_alike_desc
    if score_a is not None and score_b is not None:
        allowed &= np.minimum(score_a[:, None], score_b[None, :]) >= cfg.consensus.assign_min_score
    if veto is not None:
        allowed &= ~veto
    return np.where((dist < cfg.assign_gate_sigma) & allowed, cost, _NOT_ALLOWED)


def _one_to_one(gated: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Hungarian assignment on a `_gated_cost` (Va, Vb) without its refused pairs: (P, 2) int32
    pairs and their network scores."""
    r, c = linear_sum_assignment(gated)
    ok = gated[r, c] < _NOT_ALLOWED
    r, c = r[ok], c[ok]
    return np.stack([r, c], axis=1).astype(np.int32), P[r, c]


def mutual_pairs(score: np.ndarray, threshold: float, higher_is_better: bool = True) -> np.ndarray:
    """(P, 2) one-to-one pairs by Hungarian on a score matrix, kept beyond the threshold."""
    if score.size == 0:
        return np.zeros((0, 2), np.int32)
    cost = -score if higher_is_better else score
    r, c = linear_sum_assignment(cost)
    ok = score[r, c] > threshold if higher_is_better else score[r, c] < threshold
    return np.column_stack([r[ok], c[ok]]).astype(np.int32).reshape(-1, 2)


class RMNetOnlyMatcher(RMNetMatcher):
    """Ablation: the network's one-to-one pairs above 0.5, no geometric verification, no transform."""

    name = "rmnet-only"
    pairs_from_transform = False    # the ablation judges the network's own pairs

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        if own.num_vehicles < 2 or other.num_vehicles < 2:
            return MatchResult()
        P, _, _ = self.probabilities(own, other)
        pairs = mutual_pairs(P, 0.5)
        return MatchResult(pairs=pairs, scores=P[pairs[:, 0], pairs[:, 1]] if len(pairs) else np.zeros(0),
                           descriptor_scale=1.0 if ctx.descriptor_scale is None else ctx.descriptor_scale)


class GeometryMatcher:
    """Ablation: the verification search with every pair a candidate and no appearance (within the budget)."""

    name = "geometry"

    def __init__(self, config: RMNetConfig = RMNetConfig()) -> None:
        self.cfg = replace(config, seeds=10**6, min_support=0.5)

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        t0 = time.thread_time()
        if own.num_vehicles < 2 or other.num_vehicles < 2:
            return MatchResult()
        A, B = observe(own), observe(other)
        P = np.full((own.num_vehicles, other.num_vehicles), 0.5)
        cand = np.argwhere(np.ones(P.shape, bool))
        return verify(own, other, ctx, P, A, B, self.cfg, t0, candidates=cand, use_appearance=False)


class DescriptorMatcher:
    """Ablation: one-to-one pairs by appearance-descriptor distance alone (below `gate`), no transform."""

    name = "descriptor"

    def __init__(self, gate: float = 0.30) -> None:
        self.gate = gate

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        if own.num_vehicles == 0 or other.num_vehicles == 0:
            return MatchResult()
        scale = 1.0 if ctx.descriptor_scale is None else ctx.descriptor_scale
        D = scaled_distance(own.vehicle_features, other.vehicle_features, scale)
        pairs = mutual_pairs(D, self.gate, higher_is_better=False)
        return MatchResult(pairs=pairs, scores=1 - D[pairs[:, 0], pairs[:, 1]] if len(pairs) else np.zeros(0),
                           descriptor_scale=scale)
