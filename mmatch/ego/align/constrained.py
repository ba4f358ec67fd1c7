"""The `constrained` aligner: matched vehicles, background and heading prior in one least-squares fit.

Starts from the matcher's transform when it gives one, from a weighted Kabsch on the
matched vehicles, and, when the matcher gives no transform, from each matched pair alone
under each velocity-heading yaw (a pair whose shared points belong to something else
cannot then spoil every start). Each start is refined by Gauss-Newton (refine.py) in which only the matched pairs
may act as vehicle terms, each weighted by its two views' line-of-sight covariances, so a
pair seen from two directions pins the vehicle where the rays cross; the background
(trimmed nearest neighbours) and the heading prior hold the rest. The start whose result
puts most of the other view's background on the own view's wins.

`polish` refines the transform the Fuser finally chose once more with the two vehicles'
sightings of each other: a vehicle of one view (not matched to the other view) found where
the transform puts the other radar's vehicle, moving as that radar moves along the line of
sight, is the other vehicle itself, a pair term like any matched vehicle (its radar where
`SightingModel.offsets` puts it ahead of the detection, that model's sigmas either way). With
two co-visible vehicles strung along one street, the matched pairs and a straight roadside
leave the slide along the street loose; a sighting pins it. It runs after the confidence model
has rated the candidates, so the sighting evidence (ego/confidence.py) is not confirmed by a
fit that used it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mmatch.ego.base import (AlignResult, MatchResult, SightingModel, background_tree, heading_yaws,
                             moving_otherwise, point_counts, radial_ground_speeds, sighting_gaps,
                             sighting_offsets)
from mmatch.ego.confidence import information_sum
from mmatch.ego.descriptor_scale import scaled_distance
from mmatch.ego.observations import ObservationModel, Observations, mahalanobis, observe
from mmatch.ego.refine import RefineConfig, refine_many
from mmatch.ego.rigid import distinct_best, inv2, kabsch2d, se2_to_matrix
from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class ConstrainedConfig:
    observation: ObservationModel = ObservationModel()
    refine: RefineConfig = field(default_factory=lambda: RefineConfig(
        iterations=5, vehicle_gate=6.0, desc_gate=1.01, bg_weight_total=16.0))
                                        # background weighs 16 vehicles; 5 rounds (8 until
                                        # 2026-12-07: ConsensusConfig.refine)
    score_gate_m: float = 1.0           # background points within this count as agreeing
    max_single_pair_starts: int = 8     # up to this many pairs, each also starts a fit alone
    kabsch_with_hint: bool = False      # also start from Kabsch when the matcher gives a transform
    starts_with_hint: bool = True       # also the single-pair and two-pair starts with a transform
    max_candidates: int = 8             # distinct results handed on (AlignResult.candidates)
    coarse_iterations: int = 3          # rounds for every start before the best are refined fully
    distinct_m: float = 1.0
    distinct_deg: float = 2.0
    yaw_offsets_deg: tuple[float, ...] = (-4.0, 0.0, 4.0)
    hint_yaw_only: bool = True          # with a transform, single-pair starts under its heading yaw only
    sighting_polish: bool = True        # `polish` uses the vehicles' sightings of each other (module doc)
    sighting_gate: float = 3.0          # Mahalanobis distance within which a detection is the other vehicle
    sighting: SightingModel = SightingModel()   # where a detection puts its radar; who moves otherwise
    polish_iterations: int = 8
    quick_polish_iterations: int = 3    # in a tracking frame (the matcher's quick_iterations)


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
        if (match.T_hint is None or cfg.starts_with_hint) and yaws is not None \
                and len(pairs) <= cfg.max_single_pair_starts:
            # each pair under each heading yaw (and a few degrees either side): starts that one
            # badly placed pair cannot spoil
            use = yaws
            if match.T_hint is not None and cfg.hint_yaw_only:   # the heading yaw nearest the hint's
                hint = np.arctan2(match.T_hint[1, 0], match.T_hint[0, 0])
                use = yaws[[int(np.argmin(np.abs((yaws - hint + np.pi) % (2 * np.pi) - np.pi)))]]
            for i, j in pairs:
                for y in use:
                    for dy in np.radians(cfg.yaw_offsets_deg):
                        R = np.array([[np.cos(y + dy), -np.sin(y + dy)], [np.sin(y + dy), np.cos(y + dy)]])
                        starts.append((R, A.centres[i] - R @ B.centres[j]))
        if (match.T_hint is None or cfg.starts_with_hint) and 2 <= len(pairs) <= cfg.max_single_pair_starts:
            for a in range(len(pairs)):                  # every two pairs fix a transform
                for b in range(a + 1, len(pairs)):
                    sub = pairs[[a, b]]
                    starts.append(kabsch2d(B.centres[sub[:, 1]], A.centres[sub[:, 0]]))
        if not starts:
            return AlignResult(None, f"{len(pairs)} matched vehicle(s) and no usable hint")
        allowed = np.zeros((len(A.centres), len(B.centres)), bool)
        allowed[pairs[:, 0], pairs[:, 1]] = True
        D = scaled_distance(own.vehicle_features, other.vehicle_features, match.descriptor_scale)
        bg_own, bg_other = own.background[:, :2], other.background[:, :2]
        tree = background_tree(own)
        Rs, ts = np.stack([r for r, _ in starts]), np.stack([x for _, x in starts])
        if len(Rs) > cfg.max_candidates:
            # a few rounds for every start, then the full refinement of the distinct best
            Rs, ts = refine_many(A, B, D, bg_own, bg_other, Rs, ts, yaws,
                                 replace(cfg.refine, iterations=cfg.coarse_iterations), tree, allowed)
            ok = _finite(Rs, ts)
            Rs, ts = Rs[ok], ts[ok]
            sel = _distinct(Rs, ts, _agreement(A, B, pairs, Rs, ts, bg_other, tree, cfg), cfg)
            Rs, ts = Rs[sel], ts[sel]
        Rs, ts = refine_many(A, B, D, bg_own, bg_other, Rs, ts, yaws, cfg.refine, tree, allowed)
        ok = _finite(Rs, ts)
        Rs, ts = Rs[ok], ts[ok]
        if len(Rs) == 0:
            return AlignResult(None, "alignment diverged")
        keep = _distinct(Rs, ts, _agreement(A, B, pairs, Rs, ts, bg_other, tree, cfg), cfg)
        R, t = Rs[keep[0]], ts[keep[0]]
        inl = 0.0
        if tree is not None and len(bg_other):
            d, _ = tree.query(bg_other @ R.T + t, distance_upper_bound=cfg.score_gate_m)
            inl = float(np.isfinite(d).mean())
        return AlignResult(se2_to_matrix(R, t, other.radar_height - own.radar_height), inlier_share=inl,
                           candidates=(Rs[keep], ts[keep]))

    def polish(self, own: SharedFrame, other: SharedFrame, pairs: np.ndarray, T: np.ndarray,
               descriptor_scale: float = 1.0, quick: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """T (4x4, CAV -> Ego) refined with the matched pairs `pairs` (P, 2), the background,
        the heading prior and the two vehicles' sightings of each other (module doc), and the
        information (3, 3) of (x, y, yaw) the sightings add; (T itself, None) when neither
        vehicle is seen where T puts it. quick: a tracking frame's refined prediction (fewer
        rounds: it starts near its answer)."""
        cfg = self.cfg
        if not cfg.sighting_polish:
            return T, None
        A, B = observe(own, cfg.observation), observe(other, cfg.observation)
        pairs = np.asarray(pairs, np.intp).reshape(-1, 2)
        R, t = T[:2, :2], T[:2, 3]
        seen = sightings(A, B, own, other, pairs, R, t, cfg)
        if seen is None:
            return T, None
        D = np.zeros((len(A.centres) + 1, len(B.centres) + 1))
        D[:-1, :-1] = scaled_distance(own.vehicle_features, other.vehicle_features, descriptor_scale)
        A2, B2 = _with_bodies(A, B, own, other, seen, cfg)
        rounds = cfg.quick_polish_iterations if quick else cfg.polish_iterations
        R2, t2 = refine_many(A2, B2, D, own.background[:, :2], other.background[:, :2], R[None], t[None],
                             heading_yaws(own, other), replace(cfg.refine, iterations=rounds),
                             background_tree(own), seen)
        if not _finite(R2, t2)[0]:
            return T, None
        seen[pairs[:, 0], pairs[:, 1]] = False           # the sightings alone
        i, j = np.nonzero(seen)
        return se2_to_matrix(R2[0], t2[0], T[2, 3]), pair_information(A2.centres[i], A2.cov[i], B2.centres[j],
                                                                      B2.cov[j], R2[0])


def sightings(A: Observations, B: Observations, own: SharedFrame, other: SharedFrame, pairs: np.ndarray,
              R: np.ndarray, t: np.ndarray, cfg: ConstrainedConfig = ConstrainedConfig()) -> np.ndarray | None:
    """The pairs a refinement may use under R (2, 2), t (2,) (CAV -> Ego): (Va + 1, Vb + 1) with
    the matched `pairs` (P, 2), the Ego's nearest unmatched vehicle to where the CAV's body lies
    paired with the CAV itself (column Vb), and the CAV's nearest to the Ego's body with the Ego
    itself (row Va), each only within sighting_gate (Mahalanobis, both positions' spreads) and
    not moving otherwise than that radar along the line of sight; None when neither is seen."""
    model = cfg.sighting
    allowed = np.zeros((len(A.centres) + 1, len(B.centres) + 1), bool)
    allowed[pairs[:, 0], pairs[:, 1]] = True
    gaps = sighting_gaps(R[None], t[None], A.centres, B.centres, sighting_offsets(own, other, model))
    views = ((A, own, gaps[0][0], R @ np.asarray(other.ego_velocity, float).reshape(2), pairs[:, 0]),
             (B, other, gaps[1][0], R.T @ np.asarray(own.ego_velocity, float).reshape(2), pairs[:, 1]))
    found = False
    for side, (obs, frame, d, velocity, matched) in enumerate(views):
        if not len(obs.centres):
            continue
        S = obs.cov + model.sigmas(frame)[:, None, None] ** 2 * np.eye(2)
        m2 = np.einsum("vi,vij,vj->v", d, np.linalg.inv(S), d)
        g, u = radial_ground_speeds(frame)
        m2[moving_otherwise(g, u, point_counts(frame), velocity[None], model.speed_mps,
                            model.speed_points)[0]] = np.inf
        m2[matched] = np.inf
        k = int(np.argmin(m2))
        if m2[k] < cfg.sighting_gate ** 2:
            found = True
            if side == 0:
                allowed[k, -1] = True
            else:
                allowed[-1, k] = True
    return allowed if found else None


def pair_information(a: np.ndarray, Sa: np.ndarray, b: np.ndarray, Sb: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(3, 3) information on (x, y, yaw) of the CAV -> Ego transform from pairs of one place seen
    at a (P, 2) with covariance Sa (P, 2, 2) by the Ego and at b, Sb by the CAV, rotation R (2, 2)."""
    Jy = np.column_stack([-b[:, 1], b[:, 0]]) @ R.T                         # d(R b)/dyaw, (P, 2)
    return information_sum(Jy[None], inv2(Sa + R @ Sb @ R.T)[None])[0]


def _with_bodies(A: Observations, B: Observations, own: SharedFrame, other: SharedFrame, seen: np.ndarray,
                 cfg: ConstrainedConfig) -> tuple[Observations, Observations]:
    """Both views' vehicles with the observing vehicle itself appended: its centre behind its
    radar where the other view's detection of it (`sightings` `seen`) says, with that spread."""
    model = cfg.sighting

    def plus(o: Observations, by: np.ndarray, frame: SharedFrame) -> Observations:
        k = np.flatnonzero(by)
        off = model.offsets(frame)[k[0]] if len(k) else model.body_offset_m
        sigma = model.sigmas(frame)[k[0]] if len(k) else model.sigma_m
        body, S = np.array([[0.0, -off]]), sigma ** 2 * np.eye(2)[None]
        return Observations(np.vstack([o.centres, body]), np.concatenate([o.cov, S]),
                            np.vstack([o.cam_centres, body]), np.concatenate([o.cam_cov, S]),
                            np.append(o.cam_penalty, 0.0))
    return plus(A, seen[-1, :-1], other), plus(B, seen[:-1, -1], own)


def _distinct(R: np.ndarray, t: np.ndarray, score: np.ndarray, cfg: ConstrainedConfig) -> np.ndarray:
    """Indices of the best-scored results, skipping those within distinct_m / distinct_deg of a better one."""
    return distinct_best(R, t, np.argsort(-score, kind="stable"), cfg.max_candidates, cfg.distinct_m,
                         cfg.distinct_deg)


def _finite(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(t), axis=1) & np.all(np.isfinite(R), axis=(1, 2))


def _agreement(A, B, pairs, R, t, bg_other, tree, cfg) -> np.ndarray:
    """(H,) matched pairs explained (within 3 sigma) plus 3 x the background share within the gate."""
    s = np.zeros(len(R))
    if len(pairs):
        dm = mahalanobis(A, B, R, t)[:, pairs[:, 0], pairs[:, 1]]
        s += np.clip(1 - dm / 3.0, 0, None).sum(axis=1)
    if tree is not None and len(bg_other):
        moved = bg_other @ R.transpose(0, 2, 1) + t[:, None]
        d, _ = tree.query(moved.reshape(-1, 2), distance_upper_bound=cfg.score_gate_m)
        s += 3.0 * np.isfinite(d).reshape(len(R), -1).mean(axis=1)
    return s
