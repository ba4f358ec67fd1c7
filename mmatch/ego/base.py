"""Interfaces of matchers and aligners, and the per-vehicle quantities they share."""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from mmatch.ego.memo import memo
from mmatch.numeric import lengths
from mmatch.shared import CANONICAL_FOCAL_PX, TYPICAL_SCORE, SharedFrame, lifted_scores
from mmatch.types import DESCRIPTOR_GROUPS


@dataclass
class MatchContext:
    """What a matcher may know besides the two frames.

    gt_box_pairs: (P, 2) ground-truth (own box index, other box index); only the `oracle`
    matcher reads it, and only evaluations provide it.
    prior_T: T_ego_cav (4x4) predicted from earlier frames (see ego/track.py), or None.
    prior_only: with prior_T, a matcher may skip its global search and only refine the
        prediction (a tracking frame; the fuser asks for a full search regularly).
    descriptor_scale: factor on descriptor distances for these cameras (see
        ego/descriptor_scale.py); None: the fuser's running estimate.
    """

    gt_box_pairs: np.ndarray | None = None
    prior_T: np.ndarray | None = None
    prior_only: bool = False
    descriptor_scale: float | None = None


@dataclass
class MatchResult:
    """Co-visible pairs as (own vehicle index, other vehicle index), one-to-one.

    T_hint: a coarse CAV -> Ego transform when the matcher found one on the way (4x4), else None.
    descriptor_scale: the factor the matcher put on descriptor distances (for the aligner).
    hypotheses: the refined hypotheses and their scores (for the ambiguity of the answer).
    """

    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    scores: np.ndarray = field(default_factory=lambda: np.zeros(0))
    T_hint: np.ndarray | None = None
    descriptor_scale: float = 1.0
    hypotheses: Hypotheses | None = None


@dataclass
class Hypotheses:
    """Transform hypotheses a matcher weighed, for the confidence of its answer.

    R: (H, 2, 2), t: (H, 2) other -> own planar transforms; score: (H,) the matcher's
    evidence for each (higher is better, same units across one frame pair).
    """

    R: np.ndarray
    t: np.ndarray
    score: np.ndarray


@dataclass
class AlignResult:
    """T_ego_cav (4x4) or None with the reason; inlier_share of the background fit.

    candidates: the distinct refined transforms the aligner weighed, its own choice first
    (R (K, 2, 2), t (K, 2) other -> own), for an arbiter that knows more (ego/confidence.py).
    """

    T: np.ndarray | None
    reason: str = ""
    inlier_share: float = 0.0
    candidates: tuple[np.ndarray, np.ndarray] | None = None


def vehicle_centroids(frame: SharedFrame) -> np.ndarray:
    """(V, 2) x, y of each vehicle: the centroid of its radar points, else its box-based centre."""
    out = np.asarray(frame.vehicle_centers, np.float64).reshape(-1, 2).copy()
    if len(frame.vehicle_points):
        idx = frame.vehicle_index
        counts = np.bincount(idx, minlength=frame.num_vehicles)
        sums = _group_sums(idx, frame.vehicle_points[:, :2], frame.num_vehicles)
        has = counts > 0
        out[has] = sums[has] / counts[has, None]
    return out


def _group_sums(group: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) float64 sums of `values` (N, 2) per group index 0..n-1, added in their order
    (as np.add.at adds them, at a third of its cost)."""
    return np.column_stack([np.bincount(group, weights=values[:, k], minlength=n)[:n]
                            for k in range(2)])


def detection_scores(frame: SharedFrame, typical: float = TYPICAL_SCORE) -> np.ndarray:
    """(V,) the frame's detection scores lifted to a median of at least `typical`
    (shared.lifted_scores). Once per frame inside a fusion (ego/memo.py)."""
    return memo("detection_scores", (frame,), lambda: lifted_scores(frame.vehicle_boxes[:, 4], typical), typical)


def background_tree(frame: SharedFrame) -> cKDTree | None:
    """A k-d tree of a frame's background points (x, y, its radar frame, m); None below three
    points. Once per frame inside a fusion (ego/memo.py)."""
    bg = frame.background[:, :2]
    return memo("background_tree", (frame,), lambda: cKDTree(bg) if len(bg) >= 3 else None)


def point_counts(frame: SharedFrame) -> np.ndarray:
    """(V,) number of radar points per vehicle."""
    return np.bincount(frame.vehicle_index, minlength=frame.num_vehicles)[: frame.num_vehicles]


@dataclass(frozen=True)
class FarSideModel:
    """How far beyond its point centroid a vehicle's centre lies along the line of sight, m.

    A radar sees only the faces turned to it, so the centroid of a vehicle's returns lies short
    of its centre by about half the vehicle's depth along the ray, less however far the returns
    already reach beyond the nearest one. The depth is not measured, but the camera box hints at
    it without knowing the camera: a box taller than it is wide is a vehicle seen end-on (its
    depth is its length) or a tall one (buses and lorries are long); a wide, low box is a car
    seen side-on (its depth is its width). So

        shift = base_m + per_beyond_near x (centroid range - nearest return's range, m)
                + per_aspect x (box height / box width, px / px),

    clipped to [min_m, max_m]. Fit as the median regression of the along-ray offsets that the
    true pairs of 1000 `--physics wide` hard scenes need to meet (triangulated under the true
    transform; seeds 1, 3, 4, 100, 102, 103, 2196 vehicles): mean absolute error 0.857 m for
    the best constant, 0.772 m for this. Measured end to end in docs/method.md ("Where a vehicle's
    centre lies").
    """

    base_m: float = 0.43
    per_beyond_near: float = -0.426
    per_aspect: float = 1.574
    min_m: float = -0.5
    max_m: float = 3.5

    def shifts(self, frame: SharedFrame, centroids: np.ndarray | None = None) -> np.ndarray:
        """(V,) shift of each vehicle with points, m (0 for the others); centroids: the frame's
        `vehicle_centroids` when the caller has them."""
        V = frame.num_vehicles
        out = np.zeros(V)
        if V == 0 or len(frame.vehicle_points) == 0:
            return out
        r = np.hypot(frame.vehicle_points[:, 0], frame.vehicle_points[:, 1]).astype(np.float64)
        nearest = np.full(V, np.inf)
        np.minimum.at(nearest, frame.vehicle_index, r)
        has = np.isfinite(nearest)
        c = vehicle_centroids(frame) if centroids is None else centroids
        beyond = lengths(c) - nearest
        b = np.asarray(frame.vehicle_boxes, np.float64).reshape(-1, 6)
        aspect = (b[:, 3] - b[:, 1]) / np.maximum(b[:, 2] - b[:, 0], 1.0)
        shift = self.base_m + self.per_beyond_near * np.where(has, beyond, 0.0) + self.per_aspect * aspect
        out[has] = np.clip(shift[has], self.min_m, self.max_m)
        return out


FAR_SIDE = FarSideModel()


def far_side_centres(frame: SharedFrame, model: FarSideModel = FAR_SIDE) -> np.ndarray:
    """(V, 2) vehicle centres with the near-face bias removed: vehicles with points are pushed
    along their bearing by `model.shifts` (FarSideModel); box-based centres already aim at the
    centre and stay. Once per frame inside a fusion (ego/memo.py; read-only there)."""
    return memo("far_side_centres", (frame,), lambda: _far_side_centres(frame, model), model)


def _far_side_centres(frame: SharedFrame, model: FarSideModel) -> np.ndarray:
    c = vehicle_centroids(frame)
    norm = np.maximum(lengths(c), 1e-6)
    return c + (model.shifts(frame, c) / norm)[:, None] * c


def descriptor_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(Va, Vb) Hellinger distance between 32-bin descriptors, averaged over the H, S, V groups (0-1)."""
    return memo("descriptor_distance", (a, b), lambda: _descriptor_distance(a, b))


def _descriptor_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    bc = np.zeros((len(a), len(b)))
    for ga, gb in zip(_unit_groups(a), _unit_groups(b)):
        bc += ga @ gb.T
    return np.sqrt(np.clip(1 - bc / 3, 0, 1))


def unit_descriptor_groups(x: np.ndarray) -> tuple[np.ndarray, ...]:
    """The H, S, V groups (V, 16), (V, 8), (V, 8) of descriptors x (V, 32) as square-root
    histograms of unit length, in x's dtype. A group without mass (all zero or negative: a
    sender that measured no colour) reads as the uniform histogram, as the camera driver
    describes a box without pixels: no appearance evidence either way, where a zero vector
    would be unlike every other descriptor and veto every pair."""
    s = np.sqrt(np.clip(x, 0, None))
    out = []
    for lo, hi in DESCRIPTOR_GROUPS:
        g = s[:, lo:hi]
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out.append(np.where(norm > 0, g / norm, np.asarray(1 / np.sqrt(hi - lo), g.dtype)))
    return tuple(out)


def _unit_groups(x: np.ndarray) -> tuple[np.ndarray, ...]:
    """`unit_descriptor_groups` once per descriptor array inside a fusion (ego/memo.py): a
    frame's descriptors meet the other view's and their own (graph.py)."""
    return memo("descriptor_groups", (x,), lambda: unit_descriptor_groups(x))


MIN_SPEED_FOR_HEADING = 3.0
_HEADING_PRIOR = contextvars.ContextVar("heading_prior", default=True)


@contextlib.contextmanager
def without_heading_prior() -> Iterator[None]:
    """Within this block `velocity_heading_yaws` gives None, as for a radar standing still:
    `heading_yaws` (and so every road-direction prior: the matchers' yaw gate, the aligners'
    heading terms, the confidence features) falls back on the backgrounds' road axes, and
    the road-speed consistency is unknown. For a frame pair in which a vehicle is turning (ego/track/predict.py
    detects it): its heading lies along no road then, and a radar ahead of the rear axle
    sees its own velocity swing sideways by yaw rate x lever arm (13 deg at 0.6 rad/s, 2 m,
    5.4 m/s), so the velocity directions would pull the yaw the wrong way."""
    token = _HEADING_PRIOR.set(False)
    try:
        yield
    finally:
        _HEADING_PRIOR.reset(token)


def heading_yaws(own: SharedFrame, other: SharedFrame) -> np.ndarray | None:
    """Candidate yaws (rad) of T_ego_cav from the road directions both views show, or None.

    Vehicles drive along the road, and roads meet at right angles, so one road direction of
    each view (`road_angles`) fixes the yaw up to a multiple of 90 deg: yaw = a_own - a_other
    + k * pi / 2. The directions are the radars' velocities (`velocity_heading_yaws`) or,
    where a radar stands still or turns, the backgrounds' road axes. None when neither gives them.
    Roads that cross at other angles: `crossing_allowance` widens the crossing candidates' gate.
    """
    return _yaws(road_angles(own, other))


def velocity_heading_yaws(own: SharedFrame, other: SharedFrame) -> np.ndarray | None:
    """The heading yaws of `heading_yaws` from the two radars' own velocities alone, or None
    when either stands still (below MIN_SPEED_FOR_HEADING) or has no ego-motion estimate, and
    within `without_heading_prior` (a turning vehicle's velocity is not along the road)."""
    return _yaws(_velocity_angles(own, other))


def road_angles(own: SharedFrame, other: SharedFrame) -> tuple[float, float] | None:
    """One road direction of each view (rad, its own radar frame): the velocities' when both
    give one, else the road axes' (`road_axis`) when both backgrounds show a clear direction,
    else None. `heading_yaws` counts its candidates from these."""
    angles = _velocity_angles(own, other)
    return angles if angles is not None else _axis_angles(own, other)


def _yaws(angles: tuple[float, float] | None) -> np.ndarray | None:
    return None if angles is None else angles[0] - angles[1] + np.arange(4) * np.pi / 2


def _velocity_angles(own: SharedFrame, other: SharedFrame) -> tuple[float, float] | None:
    """The two radars' directions of travel (rad, each its own frame), or None (see
    `velocity_heading_yaws`). Once per frame pair and heading-prior setting inside a fusion
    (ego/memo.py): the matcher, the aligner and the confidence model all ask."""
    prior = _HEADING_PRIOR.get()
    return memo("velocity_angles", (own, other), lambda: _directions_of_travel(own, other, prior), prior)


def _directions_of_travel(own: SharedFrame, other: SharedFrame, prior: bool) -> tuple[float, float] | None:
    ve, vc = np.asarray(own.ego_velocity, float), np.asarray(other.ego_velocity, float)
    if not (prior and np.all(np.isfinite(ve)) and np.all(np.isfinite(vc))):
        return None
    if np.linalg.norm(ve) < MIN_SPEED_FOR_HEADING or np.linalg.norm(vc) < MIN_SPEED_FOR_HEADING:
        return None
    return float(np.arctan2(ve[1], ve[0])), float(np.arctan2(vc[1], vc[0]))


ROAD_AXIS_PAIR_M = 5.0          # background point pairs closer than this vote for a direction
ROAD_AXIS_MIN_STRENGTH = 0.1    # 0-1 agreement of their directions (mod 90 deg) needed in each view
ROAD_AXIS_MIN_POINTS = 10


def road_axis(frame: SharedFrame) -> tuple[float, float]:
    """The dominant direction (rad, modulo 90 deg) of a view's background and its strength 0-1.

    Guardrails, kerbs, facades and parked cars line the roads, so nearby background points
    lie along the road axes: each pair closer than ROAD_AXIS_PAIR_M votes with its direction,
    folded modulo 90 deg (4 x angle on the unit circle; roads meet at right angles); the
    mean vote's angle / 4 is the axis and its length the strength (0: no direction). On 300
    wide scenes (seeds 1, 3, 4) the two views' axes give the relative yaw within 10 deg in
    96 % of scenes where both strengths reach 0.1 (94 % of them)."""
    return memo("road_axis", (frame,), lambda: _road_axis(np.asarray(frame.background, float)[:, :2]))


def _road_axis(bg: np.ndarray) -> tuple[float, float]:
    if len(bg) < ROAD_AXIS_MIN_POINTS:
        return float("nan"), 0.0
    pairs = cKDTree(bg).query_pairs(ROAD_AXIS_PAIR_M, output_type="ndarray")
    if len(pairs) < ROAD_AXIS_MIN_POINTS:
        return float("nan"), 0.0
    v = bg[pairs[:, 1]] - bg[pairs[:, 0]]
    m = np.exp(4j * np.arctan2(v[:, 1], v[:, 0])).mean()
    return float(np.angle(m) / 4), float(abs(m))


def _axis_angles(own: SharedFrame, other: SharedFrame) -> tuple[float, float] | None:
    """The two views' road axes (`road_axis`), or None when either shows no clear direction."""
    a_own, s_own = road_axis(own)
    a_other, s_other = road_axis(other)
    return None if min(s_own, s_other) < ROAD_AXIS_MIN_STRENGTH else (a_own, a_other)


CROSS_BAND_DEG = 35.0


def crossing_allowance(own: SharedFrame, other: SharedFrame,
                       band_deg: float = CROSS_BAND_DEG) -> np.ndarray | None:
    """(4,) rad: how much farther than a yaw gate each `heading_yaws` candidate lets a
    hypothesis lie, or None without the velocities' prior.

    Roads do not always cross at right angles: with the CAV on a crossing road 60 deg off the
    Ego's, the true yaw lies 30 deg from every candidate. The two crossing-road candidates (odd
    k: the directions of travel a quarter turn apart) therefore admit band_deg more (a crossing
    at 45-135 deg with a 10 deg gate); the same-road ones (k = 0, 2) do not. Only the
    velocities tell a crossing from the same road: the road axes hold modulo 90 deg, so without
    the velocities (None) every candidate keeps the plain gate (docs/method.md, "Oblique junctions")."""
    if velocity_heading_yaws(own, other) is None or band_deg <= 0:
        return None
    return np.radians(band_deg) * (np.arange(4) % 2)


def yaw_gap(yaw: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Absolute angular distance (rad) of each yaw to its nearest candidate."""
    d = np.asarray(yaw)[..., None] - candidates
    return np.abs((d + np.pi) % (2 * np.pi) - np.pi).min(axis=-1)


@dataclass(frozen=True)
class SightingModel:
    """Where one vehicle's radar lies when the other view detects that vehicle, and which
    detections may be it.

    The radar sits at the front bumper: from the centre a view estimates for a detection
    (`far_side_centres`) to the radar is about half the vehicle's length ahead along its
    heading. The length is not on the wire, but the camera box hints at it: a box taller than
    long_height_m (m, its pixel height at the box depth) is a bus or lorry. Measured on the
    detections of the other vehicle itself in wide hard seeds 1, 3, 4, 100, wide easy 101 and
    nominal easy 3, 4 (1331 detections, 159 of long vehicles): along the heading 2.12 m median
    for cars (1.14-3.05 m, 10-90 %), 4.78 m for long ones (2.0-7.6 m); a box taller than 2.6 m
    held 157 of the 159 long ones and 31 of 1172 cars. body_offset_m / long_offset_m: that distance; sigma_m /
    long_sigma_m: its spread either way (m). speed_mps: a detection whose radial ground speed
    differs from that radar's own velocity along the line of sight by more is someone else,
    judged on detections of at least speed_points returns (one or two may be wheels).
    """

    body_offset_m: float = 2.3
    long_offset_m: float = 4.8
    long_height_m: float = 2.6
    sigma_m: float = 0.8
    long_sigma_m: float = 2.0
    speed_mps: float = 1.5
    speed_points: int = 3

    def long(self, frame: SharedFrame) -> np.ndarray:
        """(V,) whether each detection of `frame` looks like a long vehicle (a tall box)."""
        b = np.asarray(frame.vehicle_boxes, np.float64).reshape(-1, 6)
        return (b[:, 3] - b[:, 1]) / CANONICAL_FOCAL_PX * b[:, 5] > self.long_height_m

    def offsets(self, frame: SharedFrame) -> np.ndarray:
        """(V,) from each detection's centre estimate to the radar of the vehicle it would be, m."""
        return np.where(self.long(frame), self.long_offset_m, self.body_offset_m)

    def sigmas(self, frame: SharedFrame) -> np.ndarray:
        """(V,) the spread of `offsets`, m."""
        return np.where(self.long(frame), self.long_sigma_m, self.sigma_m)


def sighting_offsets(own: SharedFrame, other: SharedFrame,
                     model: SightingModel = SightingModel()) -> tuple[np.ndarray, np.ndarray]:
    """(Va,), (Vb,) `SightingModel.offsets` of both frames' detections."""
    return model.offsets(own), model.offsets(other)


def sighting_gaps(R: np.ndarray, t: np.ndarray, own_centres: np.ndarray, other_centres: np.ndarray,
                  offsets: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Each detection taken as the other view's vehicle, under hypotheses R (H, 2, 2), t (H, 2)
    of the other -> own transform: (H, Va, 2) from the other radar to where each own detection
    (own_centres (Va, 2)) puts it, own frame, and (H, Vb, 2) from the own radar to where each
    other detection puts that, other frame, m; a detection puts a radar `offsets` ((Va,), (Vb,),
    `sighting_offsets`) ahead of itself along that vehicle's forward (y) axis."""
    off_own, off_other = offsets
    radar_other, forward_other = t, R[:, :, 1]                              # in the own frame
    radar_own, forward_own = -np.einsum("hba,hb->ha", R, t), R[:, 1, :]       # in the other's
    return (own_centres[None] + off_own[None, :, None] * forward_other[:, None] - radar_other[:, None],
            other_centres[None] + off_other[None, :, None] * forward_own[:, None] - radar_own[:, None])


def moving_otherwise(g: np.ndarray, u: np.ndarray, n: np.ndarray, v: np.ndarray, speed_mps: float,
                     min_points: int) -> np.ndarray:
    """(H, V) whether each vehicle (radial ground speed g (V,) m/s along its line of sight u (V, 2),
    `radial_ground_speeds`; n (V,) returns) moves otherwise than velocity v (H, 2) m/s along that
    line by more than speed_mps: an unknown speed (NaN) never does, nor a vehicle of fewer than
    min_points returns (one or two may be wheels, or a false one)."""
    u = np.nan_to_num(u)
    return (np.abs(u[:, 0] * v[:, 0, None] + u[:, 1] * v[:, 1, None] - g) > speed_mps) & (n >= min_points)


def radial_ground_speeds(frame: SharedFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per vehicle: the ground velocity along the line of sight (V,) m/s and that unit line of sight (V, 2).

    From each point's Doppler plus the sender's own velocity projected on the ray
    (doppler = (v_target - v_radar) . u), the median over the vehicle's points (wheel
    returns spread between standstill and twice the body speed). NaN for vehicles without
    points or when the sender has no ego-motion estimate.
    """
    return memo("radial_ground_speeds", (frame,), lambda: _radial_ground_speeds(frame))


def _radial_ground_speeds(frame: SharedFrame) -> tuple[np.ndarray, np.ndarray]:
    V = frame.num_vehicles
    g = np.full(V, np.nan)
    u_mean = np.full((V, 2), np.nan)
    vr = np.asarray(frame.ego_velocity, float)
    if len(frame.vehicle_points) == 0 or not np.all(np.isfinite(vr)):
        return g, u_mean
    p = frame.vehicle_points[:, :3].astype(float)
    u = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-6)
    gp = frame.vehicle_points[:, 3] + u[:, :2] @ vr
    idx = frame.vehicle_index
    counts = np.bincount(idx, minlength=V)[:V]
    has = counts > 0
    g[has] = _group_medians(idx, gp, V)[has]      # wheel returns spread 0-2x the body: median
    us = _group_sums(idx, u[:, :2], V)
    us[has] /= np.maximum(lengths(us[has]), 1e-9)[:, None]
    u_mean[has] = us[has]
    return g, u_mean


def _group_medians(group: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n,) median of `values` per group index 0..n-1 (NaN for empty groups), vectorised."""
    out = np.full(n, np.nan)
    if len(values) == 0:
        return out
    order = np.lexsort((values, group))
    g, v = group[order], values[order]
    start = np.searchsorted(g, np.arange(n), "left")
    stop = np.searchsorted(g, np.arange(n), "right")
    has = stop > start
    lo = start + (stop - start - 1) // 2
    hi = start + (stop - start) // 2
    out[has] = (v[np.minimum(lo[has], len(v) - 1)] + v[np.minimum(hi[has], len(v) - 1)]) / 2
    return out


def road_speed_consistency(own: SharedFrame, other: SharedFrame, min_cos: float = 0.35,
                           tol_mps: float = 1.5) -> np.ndarray | None:
    """(4, Va, Vb) +1 / 0 / -1: is pair (i, j) one vehicle moving along a road, for yaw candidate m?

    Vehicles drive along one of the four road directions (the Ego heading turned by k x 90
    deg). For each direction the radial ground speed of a vehicle gives its speed along
    the road when the ray is not near-perpendicular to it (|cos| > min_cos). Under yaw
    candidate m (see `heading_yaws`) direction k of the Ego is direction k - m of the CAV;
    a pair is consistent (+1) when some direction gives both views the same speed within
    tol_mps (+10 %), inconsistent (-1) when none does, and 0 when no direction is
    observable in both. The directions are the velocities' or, for a radar standing still or
    turning, the road axes' (`road_angles`); None without either.
    """
    return memo("road_speed_consistency", (own, other),
                lambda: _road_speed_consistency(own, other, min_cos, tol_mps), min_cos, tol_mps, _HEADING_PRIOR.get())


def _road_speed_consistency(own: SharedFrame, other: SharedFrame, min_cos: float,
                            tol_mps: float) -> np.ndarray | None:
    angles = road_angles(own, other)
    if angles is None:
        return None
    ge, ue = radial_ground_speeds(own)
    gc, uc = radial_ground_speeds(other)

    def speeds(g, u, angle):
        a = angle + np.arange(4) * np.pi / 2
        dirs = np.column_stack([np.cos(a), np.sin(a)])                           # (4, 2)
        cos = u @ dirs.T                                                           # (V, 4)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = g[:, None] / cos
        return np.where(np.abs(cos) > min_cos, s, np.nan)

    Se = speeds(ge, ue, angles[0])                                 # (Va, 4)
    Sc = speeds(gc, uc, angles[1])                                 # (Vb, 4)
    shift = (np.arange(4)[None] - np.arange(4)[:, None]) % 4       # [m, k]: CAV direction k - m
    Sc_m = Sc[:, shift].transpose(1, 0, 2)          # (4, Vb, 4) CAV speed along Ego direction k
    diff = np.abs(Se[None, :, None, :] - Sc_m[:, None])            # (4, Va, Vb, 4)
    tol = tol_mps + 0.1 * np.abs(Se[:, None, :])
    valid = np.isfinite(diff)
    ok = (valid & (diff < tol)).any(axis=3)
    seen = valid.any(axis=3)
    return np.where(ok, 1.0, np.where(seen, -1.0, 0.0))
