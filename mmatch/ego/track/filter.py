"""A filter on T_ego_cav over time: SE(2) pose with both vehicles' yaw rates, several hypotheses.

State of one hypothesis, at the capture stamps of the last frame pair (Ego t_e, CAV t_c):
x = (px, py, yaw, w_ego, w_cav): the CAV radar's position (m) and heading (rad) in the Ego
radar frame, and each vehicle's yaw rate (rad/s); P its 5x5 covariance.

Motion: each radar moves, over its own time since its previous frame, by its Doppler-fitted
velocity (SharedFrame.ego_velocity, the mean of the previous and the new frame's) and turns
by its yaw rate; T' = inv(M_ego) T M_cav with M = SE(2) increment (rotation w dt, translation
along the mid-interval heading). Each radar's clock is its own: the Ego's motion is predicted
over the Ego's stamp difference and the CAV's over the CAV's, so the pose stays the one
between the two radars at their own capture times (DESIGN.md `gt_T_ego_cav`). Relative
velocity of the CAV in the Ego frame follows: R(yaw) v_cav - v_ego - w_ego x p. The yaw rates
are random walks; velocity errors and unmodelled motion add process noise.

Measurements: every candidate transform the frame's arbiter weighed (ego/confidence.py),
z = (px, py, yaw) with the candidate's covariance as measurement noise (floored). A candidate
updates the hypothesis it falls in (Mahalanobis gate); one that falls in none and is sure
enough starts a hypothesis of its own. So a 180 deg flip on a straight road lives beside the
right pose until motion (the two radars' velocities carry them apart) or a frame that tells
them apart decides.

Belief: each hypothesis carries a score, the log-odds that it is the right one, and its
belief b is the softmax of the scores beside "none of them" (see `step`): full searches that
land in it raise it by a weighted logit of their confidence (frames of one drive are not
independent evidence, hence the weight), full searches that answer elsewhere lower it, and
it ages while nothing lands in it; every frame, the vehicles each radar should see of the
other's under the hypothesis and misses (`view_evidence`) lower it, by what each miss weighs
for a wrong pose against the right one, beyond the misses a right pose has too. The output is
the best hypothesis with confidence b times the probability mass of its Gaussian within 2 m /
5 deg.

Frames: Ego radar frame, metres, radians, seconds.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from mmatch.ego.rigid import se2_to_matrix
from mmatch.shared import SharedFrame

CHI2_3_999 = 16.266          # 99.9 % of chi-square, 3 dof
SUCCESS_M, SUCCESS_RAD = 2.0, np.radians(5.0)
_UNIT_NORMALS = np.random.default_rng(20240614).standard_normal((512, 2))
_UIDS = itertools.count(1)


@dataclass(frozen=True)
class FilterConfig:
    """Noise, gates and belief of the pose filter (units in the names; see the module doc)."""

    velocity_sigma_mps: float = 0.15        # each radar's Doppler velocity error, per axis
    position_process_mps: float = 0.10      # unmodelled relative motion, m per sqrt(s)
    yaw_process_dps: float = 0.3            # unmodelled relative rotation, deg per sqrt(s)
    yaw_accel_sigma: float = 0.02           # random walk of each yaw rate, rad/s per sqrt(s): vehicles
                                            # mostly hold their yaw rate; a sharp turn's onset is left
                                            # to the manoeuvre test (ego/track/predict.py), which
                                            # widens it by 0.4 rad/s; an unnoticed 0.25 rad/s curve
                                            # peaks at 2.3-4.1 deg for about a second (0.1: about
                                            # 2.2; tests/track/test_filter.py)
    yaw_rate_sigma0: float = 0.02           # a new hypothesis' yaw-rate uncertainty, rad/s
    floor_m: float = 0.05                   # measurement noise floor, m
    floor_deg: float = 0.2                  # measurement noise floor, deg
    gate_chi2: float = CHI2_3_999
    spawn_confidence: float = 0.2           # a candidate this sure (and near no hypothesis) starts one
    spawn_prior: float = 0.0                # a new hypothesis' score before its own frame's logit
    max_hypotheses: int = 4
    hit_weight: float = 0.5                 # weight of a full search's confirming logit
    contradict_weight: float = 0.5          # weight of the logit of a full search's answer elsewhere
    distinct_m: float = 5.0                 # hypotheses closer than this are one (as ego/confidence.py)
    distinct_deg: float = 10.0
    half_life_s: float = 3.0                # the odds halve over this without a measurement
    min_score: float = -4.0                 # hypotheses below this log-odds are dropped
    max_score: float = 8.0                  # a score never grows beyond this (it can still be left)
    bias_share: float = 0.25                # share of a measurement's variance that does not average
                                            # out over frames (common to a drive); kept in the output
    view_found_right: float = 0.85          # share of the vehicles one radar should see of the other's
                                            # (ego/confidence.py `shared_view`) that it does see under the
                                            # right pose (0.845 over the drives of seed 400) ...
    view_found_wrong: float = 0.72          # ... and under a grossly wrong one (0.72-0.75 under the
                                            # per-frame mode's gross estimates there)
    view_weight: float = 1.0                # weight of a frame's shared-view evidence


@dataclass
class Hypothesis:
    """One candidate pose track: state x (5,), covariance P (5, 5), belief b (0-1), counts."""

    x: np.ndarray
    P: np.ndarray
    belief: float
    hits: int = 1
    misses: int = 0
    hit_now: bool = True
    score: float = 0.0                      # log-odds that it is the right one
    recent_R: np.ndarray | None = None      # mean measurement noise it took (3, 3), `_blend_noise`
    uid: int = 0                            # which hypothesis this is, frame after frame (and
                                            # through a merge that hands its score on)

    def covariance(self, cfg: "FilterConfig") -> np.ndarray:
        """(x, y, yaw) covariance to publish: the state's plus the share of the measurement noise
        that frames of one drive share (their errors do not average out)."""
        P = self.P[:3, :3].copy()
        if self.recent_R is not None:
            P += cfg.bias_share * self.recent_R
        return P

    @property
    def T(self) -> np.ndarray:
        """T_ego_cav (4x4) of the hypothesis' mean."""
        c, s = np.cos(self.x[2]), np.sin(self.x[2])
        return se2_to_matrix(np.array([[c, -s], [s, c]]), self.x[:2])

    def copy(self) -> "Hypothesis":
        return Hypothesis(self.x.copy(), self.P.copy(), self.belief, self.hits, self.misses, self.hit_now,
                          self.score, None if self.recent_R is None else self.recent_R.copy(),
                          self.uid)


@dataclass
class PoseTrack:
    """Every hypothesis about one CAV, at the capture stamps (own_stamp, other_stamp)."""

    hypotheses: list[Hypothesis]
    own_stamp: float
    other_stamp: float
    v_own: np.ndarray
    v_other: np.ndarray
    since_full: int = 0
    frames: int = 0
    extra: dict = field(default_factory=dict)
    beliefs: list[tuple[float, int, float]] = field(default_factory=list)   # (Ego stamp s, uid,
                                            # belief) of its established hypotheses, recent frames
                                            # (`Tracker.rival`)

    def best(self) -> Hypothesis | None:
        return max(self.hypotheses, key=lambda h: h.belief, default=None)


def wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def pose_of(T: np.ndarray) -> np.ndarray:
    """(px, py, yaw) of a 4x4 T_ego_cav."""
    return np.array([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0])])


def velocity_of(frame: SharedFrame) -> np.ndarray:
    """A frame's radar velocity over ground (2,) m/s in its own frame, zeros when unknown."""
    v = np.asarray(frame.ego_velocity, float).reshape(2)
    return v if np.all(np.isfinite(v)) else np.zeros(2)


def _increment(v: np.ndarray, w: float, dt: float) -> tuple[float, np.ndarray]:
    """Rotation (rad) and translation (2,) of a radar moving at v (its frame) turning at w for dt."""
    phi = w * dt
    c, s = np.cos(phi / 2), np.sin(phi / 2)
    return phi, np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]]) * dt


def motion(x: np.ndarray, v_own: np.ndarray, v_other: np.ndarray, dt_own: float, dt_other: float) -> np.ndarray:
    """The state after the Ego moved for dt_own and the CAV for dt_other (see the module doc)."""
    phi_e, d_e = _increment(v_own, x[3], dt_own)
    phi_c, d_c = _increment(v_other, x[4], dt_other)
    c, s = np.cos(x[2]), np.sin(x[2])
    p = x[:2] + np.array([c * d_c[0] - s * d_c[1], s * d_c[0] + c * d_c[1]]) - d_e
    ce, se = np.cos(-phi_e), np.sin(-phi_e)
    out = x.copy()
    out[:2] = [ce * p[0] - se * p[1], se * p[0] + ce * p[1]]
    out[2] = wrap(x[2] + phi_c - phi_e)
    return out


def _jacobian(x: np.ndarray, *args) -> np.ndarray:
    eps = np.array([1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    f0 = motion(x, *args)
    J = np.zeros((5, 5))
    for i in range(5):
        d = np.zeros(5)
        d[i] = eps[i]
        diff = motion(x + d, *args) - f0
        diff[2] = wrap(diff[2])
        J[:, i] = diff / eps[i]
    return J


def predict(h: Hypothesis, v_own: np.ndarray, v_other: np.ndarray, dt_own: float, dt_other: float,
            cfg: FilterConfig) -> Hypothesis:
    """The hypothesis moved forward (extended Kalman prediction); a new object."""
    F = _jacobian(h.x, v_own, v_other, dt_own, dt_other)
    dt = max(abs(dt_own), abs(dt_other))
    Q = np.zeros((5, 5))
    Q[:2, :2] = np.eye(2) * (cfg.velocity_sigma_mps ** 2 * (dt_own ** 2 + dt_other ** 2)
                             + cfg.position_process_mps ** 2 * dt)
    Q[2, 2] = np.radians(cfg.yaw_process_dps) ** 2 * dt
    Q[3, 3] = Q[4, 4] = cfg.yaw_accel_sigma ** 2 * dt
    out = h.copy()
    out.x = motion(h.x, v_own, v_other, dt_own, dt_other)
    out.P = F @ h.P @ F.T + Q
    return out


def measurement_noise(cov: np.ndarray | None, cfg: FilterConfig) -> np.ndarray:
    """A candidate's (x, y, yaw) covariance with the floor; a broad default when it has none."""
    floor = np.diag([cfg.floor_m ** 2, cfg.floor_m ** 2, np.radians(cfg.floor_deg) ** 2])
    if cov is None or np.shape(cov) != (3, 3) or not np.all(np.isfinite(cov)):
        return np.diag([4.0, 4.0, np.radians(5.0) ** 2])
    c = (np.asarray(cov, float) + np.asarray(cov, float).T) / 2
    return c + floor


def innovation(h: Hypothesis, z: np.ndarray, Rm: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(innovation (3,), its covariance (3, 3), squared Mahalanobis distance)."""
    y = z - h.x[:3]
    y[2] = wrap(y[2])
    S = h.P[:3, :3] + Rm
    try:
        d2 = float(y @ np.linalg.solve(S, y))
    except np.linalg.LinAlgError:
        d2 = float("inf")
    return y, S, d2


def update(h: Hypothesis, z: np.ndarray, Rm: np.ndarray) -> Hypothesis:
    """Kalman update of the hypothesis with a pose measurement z (3,) of noise Rm; a new object."""
    y, S, _ = innovation(h, z, Rm)
    H = np.zeros((3, 5))
    H[:, :3] = np.eye(3)
    K = h.P @ H.T @ np.linalg.inv(S)
    out = h.copy()
    out.x = h.x + K @ y
    out.x[2] = wrap(out.x[2])
    I_KH = np.eye(5) - K @ H
    out.P = I_KH @ h.P @ I_KH.T + K @ Rm @ K.T          # Joseph form: stays symmetric positive
    return out


def _blend_noise(recent: np.ndarray, new: np.ndarray, keep: float = 0.8) -> np.ndarray:
    """The running mean of the measurement noise a hypothesis took (`Hypothesis.recent_R`), in
    information form: keep x the old information plus (1 - keep) x the new one's. A measurement
    that leaves a direction free (a refinement without background, its yaw variance 1e5 rad^2)
    barely moved the state there, so it must not swell the published bias term: averaged as
    covariances, one such frame had made a right track's published yaw sigma 10^4 deg for
    dozens of frames, and every full search that did not land in it refused it."""
    info = keep * np.linalg.inv(recent) + (1.0 - keep) * np.linalg.inv(new)
    return np.linalg.inv((info + info.T) / 2)


def within_success(cov3: np.ndarray) -> float:
    """Probability mass of N(0, cov3) (x, y m; yaw rad) within 2 m and 5 deg (position and yaw
    taken as independent; position by a fixed sample, so the answer is deterministic)."""
    c = np.asarray(cov3, float)
    try:
        L = np.linalg.cholesky((c[:2, :2] + c[:2, :2].T) / 2 + np.eye(2) * 1e-12)
    except np.linalg.LinAlgError:
        return 0.0
    r = np.linalg.norm(_UNIT_NORMALS @ L.T, axis=1)
    p_pos = float(np.mean(r < SUCCESS_M))
    s_yaw = float(np.sqrt(max(c[2, 2], 1e-12)))
    from math import erf, sqrt
    return p_pos * erf(SUCCESS_RAD / (sqrt(2.0) * s_yaw))


def new_hypothesis(z: np.ndarray, Rm: np.ndarray, belief: float, cfg: FilterConfig) -> Hypothesis:
    P = np.zeros((5, 5))
    P[:3, :3] = Rm
    P[3, 3] = P[4, 4] = cfg.yaw_rate_sigma0 ** 2
    b = min(max(float(belief), 1e-3), 1 - 1e-3)
    return Hypothesis(np.concatenate([z, [0.0, 0.0]]), P, b, score=float(np.log(b / (1 - b))),
                      recent_R=Rm.copy(), uid=next(_UIDS))


@dataclass
class Candidate:
    """A transform the frame weighed: pose z (3,), covariance (3, 3) or None, confidence p (0-1).

    informative: whether the frame's evidence for it tells a right pose from a wrong one
    (ego/confidence.py `tells_poses_apart`). One that does not (a refinement on the background
    alone, one vehicle pair) is unsure because a single frame cannot choose, not because the
    pose is wrong: it moves the hypothesis it lands in but neither raises, lowers nor
    contradicts any score, and the hypothesis ages as if nothing had landed (`step`). While a
    radar manoeuvres, and shortly after, every candidate is informative (the tracker's
    `Prediction.settling`, ego/track/predict.py), and so is one at least 0.5 sure: more likely
    right than not, it confirms the hypothesis it lands in (on a seed-800 drive, one pair at
    0.74-0.97 frame after frame had otherwise let an 11 m slide take the track over)."""

    z: np.ndarray
    cov: np.ndarray | None
    p: float
    informative: bool = True


def _logit(p: float) -> float:
    p = min(max(float(p), 1e-3), 1 - 1e-3)
    return float(np.log(p / (1 - p)))


def _distinct(h: Hypothesis, z: np.ndarray, cfg: FilterConfig) -> bool:
    return bool(np.hypot(*(h.x[:2] - z[:2])) > cfg.distinct_m or abs(wrap(h.x[2] - z[2])) > np.radians(cfg.distinct_deg))


def view_evidence(expected: float, missed: float, cfg: FilterConfig) -> float:
    """A frame's shared-view evidence for a hypothesis under which `expected` vehicles should
    have been seen by the other radar and `missed` of them were not: the log-likelihood ratio
    of each miss (right pose against wrong), less what the right pose misses on average, so
    that a right track neither gains nor loses on average. The vehicles that were seen are not
    counted: they are mostly the matched ones, whose evidence the candidates carry already."""
    pr, pw = cfg.view_found_right, cfg.view_found_wrong
    return cfg.view_weight * ((1 - pr) * expected - missed) * np.log((1 - pw) / (1 - pr))


def step(track: PoseTrack, candidates: list[Candidate], dt: float, cfg: FilterConfig,
         independent: bool = True, view: list[tuple[float, float]] | None = None) -> bool:
    """Update every hypothesis of `track` (already predicted to this frame, dt s after the last)
    with the frame's candidates; spawn, merge and prune. Returns whether the best hypothesis
    took a measurement this frame.

    Each hypothesis keeps a score: the log-odds that it is the right one (its belief is the
    softmax over the hypotheses and "none of them"). A hypothesis takes the state of one
    candidate in its gate: on a full search the surest (the nearest of equally sure ones), for
    the nearest is mostly the refinement of the hypothesis' own prediction, which keeps whatever
    bias it has (a track that started 2.8 m off stayed 1.2-2.9 m off for 3 s while full searches
    found the truth at 0.97-0.99; taking the surest, the wrong frames of fresh drives 2100-2300
    fell 47 -> 9); otherwise the nearest. independent: the candidates come from a
    full search that did not know the track: a candidate in a hypothesis' gate adds
    `hit_weight` x logit(its confidence) (clipped), a frame whose best candidate lies elsewhere
    (farther than distinct_m / distinct_deg) takes `contradict_weight` x logit of that one's
    confidence, and a sure candidate in no hypothesis starts one. Otherwise the candidates
    refine the track's own prediction: they update the state of the hypothesis they fall in
    and can only lower its score (a poor fit), never raise it. A candidate that is not
    `Candidate.informative` counts for neither: it updates the state of the hypothesis it falls
    in, which ages as when nothing lands in it (it gave 0.5 x logit(0.1-0.3) a frame before,
    and a right track lost its belief within a second of its drive sharing no vehicles; with
    the exceptions `Candidate` names, the tuning drives' tracked success 0.876 -> 0.889, README
    "Over time").
    view: per hypothesis of the track (in order), (expected, missed) vehicles of the shared view
    at its predicted pose (`view_evidence`), or None."""
    noise = [measurement_noise(c.cov, cfg) for c in candidates]
    sure = np.array([c.p for c in candidates])
    ageing = np.log(2.0) * max(dt, 0.0) / max(cfg.half_life_s, 1e-6)    # log-odds lost unconfirmed
    used: set[int] = set()
    out = []
    for i, h in enumerate(track.hypotheses):
        d2 = np.array([innovation(h, c.z, R)[2] for c, R in zip(candidates, noise)])
        gated = np.flatnonzero(d2 < cfg.gate_chi2)
        h2 = h.copy()
        if len(gated):
            if independent:                        # the surest, then the nearest (see above)
                k = int(gated[np.lexsort((d2[gated], -sure[gated]))[0]])
            else:
                k = int(gated[np.argmin(d2[gated])])
            told = [candidates[g].p for g in gated if candidates[g].informative]
            h2 = update(h, candidates[k].z, noise[k])
            h2.hits, h2.misses, h2.hit_now = h.hits + bool(told), 0, True
            h2.recent_R = noise[k] if h.recent_R is None else _blend_noise(h.recent_R, noise[k])
            used.update(int(g) for g in gated)
            if told:
                e = cfg.hit_weight * float(np.clip(_logit(max(told)), -1.0, 3.0))
                h2.score = h.score + (e if independent else min(e, 0.0))
            else:                                  # moved, not confirmed: it ages
                h2.score -= ageing
        else:
            h2.misses, h2.hit_now = h.misses + 1, False
            far = [c.p for c in candidates if c.informative and _distinct(h, c.z, cfg)]
            if independent and far:                # the search found its answer elsewhere
                h2.score -= cfg.contradict_weight * max(_logit(max(far)), 0.5)
            h2.score -= ageing
        if view is not None:
            h2.score += view_evidence(*view[i], cfg)
        out.append(h2)
    for k in sorted(range(len(candidates)), key=lambda k: -candidates[k].p):   # the surest first: a
        c = candidates[k]                      # less sure one within distinct_m would block it
        if not independent or k in used or c.p < cfg.spawn_confidence:
            continue
        if any(not _distinct(h, c.z, cfg) for h in out):
            continue
        h = new_hypothesis(c.z, noise[k], 0.0, cfg)
        h.score = cfg.spawn_prior + _logit(c.p)          # one frame: its own calibrated confidence
        out.append(h)
    out = _merge(out, cfg)
    out = [h for h in out if h.score > cfg.min_score]
    for h in out:
        h.score = float(np.clip(h.score, cfg.min_score, cfg.max_score))
    _beliefs(out)
    out.sort(key=lambda h: -h.belief)
    track.hypotheses = out[: cfg.max_hypotheses]
    _beliefs(track.hypotheses)
    best = track.best()
    return bool(best is not None and best.hit_now)


def _beliefs(hyps: list[Hypothesis]) -> None:
    """belief = softmax of the scores against "none of them" (score 0)."""
    if not hyps:
        return
    s = np.array([h.score for h in hyps])
    m = max(s.max(), 0.0)
    w = np.exp(s - m)
    total = w.sum() + np.exp(-m)
    for h, x in zip(hyps, w):
        h.belief = float(x / total)


def _merge(hyps: list[Hypothesis], cfg: FilterConfig) -> list[Hypothesis]:
    """Hypotheses closer than distinct_m / distinct_deg are one: the best-scored one's score stays,
    with the state of the one that took this frame's measurement (a drifted track re-acquires)."""
    hyps = sorted(hyps, key=lambda h: -h.score)
    out: list[Hypothesis] = []
    for h in hyps:
        for i, o in enumerate(out):
            if not _distinct(o, h.x[:3], cfg):
                if h.hit_now and not o.hit_now:
                    h.score, h.hits, h.uid = o.score, max(o.hits, h.hits), o.uid
                    out[i] = h
                break
        else:
            out.append(h)
    return out
