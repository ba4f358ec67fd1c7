"""Carrying T_ego_cav across frames: prediction from both radars' motion, trust, tracked fusion."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.confidence import ConfidenceConfig
from mmatch.ego.rigid import se2_to_matrix
from mmatch.ego.track import TrackConfig, Tracker
from mmatch.ego.track.predict import MAX_BELIEF_RECORDS, MAX_YAW_RATE
from mmatch.ego.track.filter import Candidate, new_hypothesis, pose_of, within_success
from mmatch.fusion import Fuser, FusionConfig
from mmatch.metrics import rre_deg, rte_m
from mmatch.shared import CANONICAL_FOCAL_PX, SharedFrame


def _rot(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _world_T(x: float, y: float, yaw_deg: float) -> np.ndarray:
    return se2_to_matrix(_rot(yaw_deg), np.array([x, y]))


def _boxes(vehicles: np.ndarray) -> np.ndarray:
    """(V, 6) canonical-image boxes of 1.8 m x 1.5 m cars at (x, y) (radar frame, camera looking
    along +y beside it), score 0.9, depth their distance: what a camera would report."""
    x, y = vehicles[:, 0], np.maximum(vehicles[:, 1], 1.0)
    f = CANONICAL_FOCAL_PX
    return np.column_stack([f * (x - 0.9) / y, -f * 1.0 / y, f * (x + 0.9) / y, f * 0.5 / y,
                            np.full(len(x), 0.9), np.hypot(x, y)]).astype(np.float32).reshape(-1, 6)


def _frame(sender: str, stamp: float, velocity, vehicles: np.ndarray, background: np.ndarray,
           car_velocity: np.ndarray | None = None) -> SharedFrame:
    """A shared frame with one radar point per vehicle (moving at car_velocity (V, 2), this
    radar's frame, m/s; parked without); the reader corrects its far side."""
    V = len(vehicles)
    u = vehicles / np.maximum(np.linalg.norm(vehicles, axis=1, keepdims=True), 1e-6)
    near = vehicles - 1.4 * u
    rel = (np.zeros((V, 2)) if car_velocity is None else car_velocity) - np.asarray(velocity, float)
    doppler = np.einsum("vi,vi->v", u, rel)
    return SharedFrame(sender, 0, stamp, 0.5, ego_velocity=np.asarray(velocity, float),
                       vehicle_points=np.c_[near, np.zeros(V), doppler, np.full(V, 10.0)].astype(np.float32),
                       vehicle_index=np.arange(V, dtype=np.int32),
                       vehicle_boxes=_boxes(vehicles),
                       vehicle_box_index=np.arange(V, dtype=np.int32),
                       vehicle_centers=vehicles.astype(np.float32).reshape(-1, 2),
                       vehicle_features=np.tile(np.eye(32, dtype=np.float32)[[0, 16, 24]].sum(0), (V, 1)),
                       background=np.c_[background, np.zeros(len(background))].astype(np.float32))


class World:
    """Two radars driving straight (the CAV turned 90 deg), walls fixed in the world, three cars
    driving along the Ego's road at 8 m/s (the CAV side shares moving vehicles only)."""

    def __init__(self) -> None:
        self.v_ego, self.v_cav = np.array([0.0, 12.0]), np.array([0.0, 9.0])   # own-frame velocities
        self.cars = np.array([[-3.0, 40.0], [4.0, 46.0], [-6.0, 55.0]])   # at t = 5 s
        self.v_cars = np.array([0.0, 8.0])                                   # all drive along +y
        wall = np.column_stack([np.full(80, 9.0), np.linspace(0, 90, 80)])
        wall2 = np.column_stack([np.linspace(-30, 9, 40), np.full(40, 70.0)])
        self.walls = np.vstack([wall, wall2, wall * [-1, 1]])

    def pose(self, who: str, t: float) -> np.ndarray:
        if who == "ego":
            return _world_T(0.0, self.v_ego[1] * t, 0.0)
        return _world_T(60.0 - self.v_cav[1] * t, 45.0, 90.0)     # drives towards -x in the world

    def truth(self, t_ego: float, t_cav: float) -> np.ndarray:
        return np.linalg.inv(self.pose("ego", t_ego)) @ self.pose("cav", t_cav)

    def frame(self, who: str, t: float, with_cars: bool) -> SharedFrame:
        inv = np.linalg.inv(self.pose(who, t))

        def local(p: np.ndarray) -> np.ndarray:
            return p @ inv[:2, :2].T + inv[:2, 3]
        bg = local(self.walls)
        bg = bg[(bg[:, 1] > 1) & (np.abs(np.arctan2(bg[:, 0], bg[:, 1])) < np.radians(60))]
        cars = local(self.cars + self.v_cars * (t - 5.0)) if with_cars else np.zeros((0, 2))
        v = self.v_ego if who == "ego" else self.v_cav
        return _frame(who, t, v, cars, bg, np.tile(inv[:2, :2] @ self.v_cars, (len(cars), 1)))

    def drive(self, n: int, t0: float = 3.0):
        """n frame pairs at 20 Hz, the Ego capturing 20 ms after the CAV: (t, own, other)."""
        for k in range(n):
            t = t0 + 0.05 * k
            yield t, self.frame("ego", t + 0.02, True), self.frame("cav", t, True)


def _commit(tr: Tracker, own: SharedFrame, oth: SharedFrame, T: np.ndarray, p: float = 0.9):
    pred = tr.predict(own, oth)
    cov = np.diag([0.3, 0.3, np.radians(1.0)]) ** 2
    return tr.commit(own, oth, pred, [Candidate(pose_of(T), cov, p)], full_search=True)


def _straight_start(w: "World", tr: Tracker) -> float:
    """Three frames of a believed track on the straight drive from t = 1 s; returns the next t."""
    t = 1.0
    for _ in range(3):
        own, oth = w.frame("ego", t, True), w.frame("cav", t, True)
        _commit(tr, own, oth, w.truth(t, t), p=0.95)
        t += 0.05
    return t


def _born_in_turn(w: "World", tr: Tracker, t: float, turning: np.ndarray, cov: np.ndarray) -> list:
    """A sure candidate 8 m off the track at t (a distinct pose: a new hypothesis) while the CAV
    turns; the hypotheses of one frame predicted to the next."""
    from dataclasses import replace

    own, oth = w.frame("ego", t, True), replace(w.frame("cav", t, True), ego_velocity=turning)
    far = Candidate(pose_of(w.truth(t, t)) + [8.0, 0.0, 0.0], cov, 0.99)
    tr.commit(own, oth, tr.predict(own, oth), [far], full_search=True)
    t += 0.05
    own, oth = w.frame("ego", t, True), replace(w.frame("cav", t, True), ego_velocity=turning)
    return [h for h in tr.predict(own, oth).track.hypotheses if h.hits == 1]


def test_prediction_follows_both_radars_motion():
    w = World()
    tr = Tracker(TrackConfig(max_age_s=2.0))
    own0, oth0 = w.frame("ego", 2.02, True), w.frame("cav", 2.0, True)
    hyp, hit = _commit(tr, own0, oth0, w.truth(2.02, 2.0))
    assert hyp is not None and hit and abs(hyp.belief - 0.9) < 0.01     # one frame: its own confidence
    own1, oth1 = w.frame("ego", 2.52, True), w.frame("cav", 2.50, True)
    pred = tr.predict(own1, oth1).prior_T
    truth = w.truth(2.52, 2.50)
    assert rte_m(truth, pred) < 1e-6 and rre_deg(truth, pred) < 1e-6
    # stale tracks are dropped
    assert tr.predict(w.frame("ego", 5.0, True), w.frame("cav", 5.0, True)).prior_T is None
    assert tr.track("cav") is None


def test_frames_lost_for_more_than_half_a_second_end_the_track():
    """TrackConfig's default max_age_s: 0.5 s of lost frames may hide a whole turn; the track
    is dropped and starts again instead of publishing a stale prediction."""
    w = World()
    tr = Tracker(TrackConfig())
    assert TrackConfig().max_age_s == 0.5
    _commit(tr, w.frame("ego", 1.0, True), w.frame("cav", 1.0, True), w.truth(1.0, 1.0))
    assert tr.predict(w.frame("ego", 1.45, True), w.frame("cav", 1.45, True)).prior_T is not None
    assert tr.predict(w.frame("ego", 1.6, True), w.frame("cav", 1.6, True)).prior_T is None
    assert tr.track("cav") is None


def test_a_far_estimate_starts_a_rival_and_a_near_one_refines_the_track():
    w = World()
    tr = Tracker(TrackConfig(max_age_s=2.0))
    for k in range(4):
        t = 1.0 + 0.05 * k
        _commit(tr, w.frame("ego", t, True), w.frame("cav", t, True), w.truth(t, t), p=0.8)
    established = tr.track("cav").best().belief
    t = 1.2
    wrong = w.truth(t, t) @ se2_to_matrix(_rot(0), np.array([0.0, 12.0]))
    best, _ = _commit(tr, w.frame("ego", t, True), w.frame("cav", t, True), wrong, p=0.8)
    hyps = tr.track("cav").hypotheses
    assert len(hyps) == 2                                        # the slid estimate lives beside it
    assert rte_m(w.truth(t, t), best.T) < 0.5 and best.belief < established
    near = w.truth(t + 0.05, t + 0.05) @ se2_to_matrix(_rot(0.5), np.array([0.3, 0.0]))
    best, hit = _commit(tr, w.frame("ego", t + 0.05, True), w.frame("cav", t + 0.05, True), near, p=0.8)
    assert hit and rte_m(w.truth(t + 0.05, t + 0.05), best.T) < 0.3
    assert not Tracker(TrackConfig(max_age_s=0.0)).commit(
        w.frame("ego", 1.0, True), w.frame("cav", 1.0, True), None, [], True)[0]


def test_a_confident_first_frame_is_published_at_once_and_a_less_sure_one_waits_for_a_second():
    """TrackConfig.sure_at_once: a hypothesis one frame has found is published when that frame
    is at least this sure of it; below, it waits until a second frame agrees (min_hits)."""
    w = World()
    own, oth = w.frame("ego", 4.97, True), w.frame("cav", 4.95, True)
    fuser = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0, sure_at_once=None)))
    held = fuser.fuse(own, oth)
    assert held.status == "no-estimate" and held.reason == "unconfirmed"       # sure, but one frame
    # a frame's confirmation makes the track as sure as its belief times its spread's mass within
    # 2 m / 5 deg (the spread of one frame's measurement matters here)
    spread = within_success(held.covariance)
    sure = fuser.tracker.track(oth.sender).best().belief * spread
    assert spread < 0.9 and sure >= 0.75 and rte_m(w.truth(4.97, 4.95), held.refused_T) < 1.0
    # ... and refused, it is published below the threshold: sure_at_once is 1 here
    assert held.confidence == pytest.approx(sure * 0.6) and held.confidence < 0.6
    # (a threshold of 0 has nothing to stay below: the track's own confidence)
    everything = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0, sure_at_once=None),
                                    confidence=ConfidenceConfig(threshold=0.0))).fuse(own, oth)
    assert everything.reason == "unconfirmed" and everything.confidence == pytest.approx(sure)
    lower = TrackConfig(max_age_s=2.0, sure_at_once=sure - 1e-6)
    higher = TrackConfig(max_age_s=2.0, sure_at_once=sure + 1e-6)
    at_once = Fuser(FusionConfig(track=lower)).fuse(own, oth)
    assert at_once.status == "fused" and at_once.confidence == sure and len(at_once.pairs) == 3
    assert np.allclose(at_once.T_ego_cav, held.refused_T)
    waits = Fuser(FusionConfig(track=higher)).fuse(own, oth)
    assert waits.status == "no-estimate" and waits.reason == "unconfirmed"


def test_a_frame_without_vehicles_is_fused_from_the_track():
    w = World()
    fuser = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0, sure_at_once=None)))
    unconfirmed = fuser.fuse(w.frame("ego", 4.97, True), w.frame("cav", 4.95, True))
    assert unconfirmed.status == "no-estimate" and unconfirmed.reason == "unconfirmed"  # one frame
    assert rte_m(w.truth(4.97, 4.95), unconfirmed.refused_T) < 1.0
    first = fuser.fuse(w.frame("ego", 5.02, True), w.frame("cav", 5.0, True))       # two agree
    assert first.status == "fused" and len(first.pairs) == 3
    assert rte_m(w.truth(5.02, 5.0), first.T_ego_cav) < 1.0
    later = fuser.fuse(w.frame("ego", 5.52, True), w.frame("cav", 5.5, False))   # the CAV sees no car
    assert later.status == "fused" and len(later.pairs) == 0
    truth = w.truth(5.52, 5.5)
    assert rte_m(truth, later.T_ego_cav) < 1.0 and rre_deg(truth, later.T_ego_cav) < 2.0
    # without tracking the same frame has nothing to go on
    plain = Fuser().fuse(w.frame("ego", 5.52, True), w.frame("cav", 5.5, False))
    assert plain.status == "no-estimate" and "no vehicles" in plain.reason


def test_full_searches_come_back_regularly_while_tracking():
    w = World()
    fuser = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0, full_search_every=3, sure_at_once=None)))
    quick = []
    for k, (t, own, oth) in enumerate(w.drive(9)):
        quick.append(fuser.tracker.tracking_only(fuser.tracker.predict(own, oth)))
        res = fuser.fuse(own, oth)
        truth = w.truth(t + 0.02, t)
        if k == 0:                                               # published once a second frame agrees
            assert res.status == "no-estimate" and res.reason == "unconfirmed"
            continue
        assert res.status == "fused" and rte_m(truth, res.T_ego_cav) < 1.0 and rre_deg(truth, res.T_ego_cav) < 2.0
        assert len(res.pairs) == 3
    assert not quick[0] and any(quick)                           # the first frame searches
    runs = "".join("q" if q else "f" for q in quick)
    assert "qqq" not in runs                                     # never more than 2 tracking frames in a row


def test_the_regular_search_runs_after_the_frame_and_a_caller_that_never_asks_gets_the_same():
    """A believed track's regular full search is deferred (TrackConfig.defer_search): the frame
    publishes its refined prediction, `run_deferred` then searches from the same prediction and
    resets the count; `fuse` runs what is left first, so results do not depend on the call."""
    from dataclasses import replace

    w = World()
    cfg = TrackConfig(max_age_s=2.0, full_search_every=3)
    eager, lazy = Fuser(FusionConfig(track=cfg)), Fuser(FusionConfig(track=cfg))
    inline = Fuser(FusionConfig(track=replace(cfg, defer_search=False)))
    deferred = []
    for t, own, oth in w.drive(12):
        a, b, c = eager.fuse(own, oth), lazy.fuse(own, oth), inline.fuse(own, oth)
        assert a.status == b.status == c.status
        if a.status == "fused":
            assert np.array_equal(a.T_ego_cav, b.T_ego_cav)
            truth = w.truth(t + 0.02, t)
            for r in (a, c):
                assert rte_m(truth, r.T_ego_cav) < 1.0 and rre_deg(truth, r.T_ego_cav) < 2.0
        n = eager.run_deferred()
        deferred.append(n)
        if n:
            assert eager.tracker.track("cav").since_full == 1
    assert sum(deferred) >= 3 and max(deferred) == 1
    assert lazy.run_deferred() == deferred[-1]


def test_a_second_cav_does_not_wait_for_the_first_ones_deferred_search():
    from dataclasses import replace

    w = World()
    fuser = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0, full_search_every=3)))
    pending = []
    for _, own, oth in w.drive(8):
        fuser.fuse(own, oth)
        fuser.fuse(own, replace(oth, sender="cav2"))        # the same view from a second CAV
        pending.append(fuser.run_deferred("cav"))            # still there after cav2's fusion
        fuser.run_deferred()
    assert sum(pending) >= 2


def test_a_turning_radar_is_a_manoeuvre_that_searches_and_loosens_the_yaw_rate():
    """A radar ahead of the rear axle sees its velocity swing sideways when its vehicle starts to
    turn: the next frame searches globally, without the road-direction prior, and the turning
    vehicle's yaw rate becomes uncertain; a straight drive with Doppler noise is no manoeuvre."""
    from dataclasses import replace

    from mmatch.ego.base import heading_yaws, velocity_heading_yaws, without_heading_prior

    w = World()
    cfg = TrackConfig(max_age_s=2.0, full_search_every=10, lever_arm_m=0.0)   # the loosening alone
    tr = Tracker(cfg)
    rng = np.random.default_rng(3)
    for k in range(4):                                           # straight, 0.1 m/s velocity noise
        t = 1.0 + 0.05 * k
        own = replace(w.frame("ego", t, True), ego_velocity=w.v_ego + rng.normal(0, 0.1, 2))
        oth = replace(w.frame("cav", t, True), ego_velocity=w.v_cav + rng.normal(0, 0.1, 2))
        pred = tr.predict(own, oth)
        assert not pred.manoeuvre
        _commit(tr, own, oth, w.truth(t, t), p=0.95)
    assert tr.tracking_only(tr.predict(own, oth))
    before = tr.track("cav").best().P[4, 4]
    t = 1.2
    turning = replace(w.frame("cav", t, True), ego_velocity=np.array([-1.2, 9.0]))   # 7.6 deg sideways
    pred = tr.predict(w.frame("ego", t, True), turning)
    assert pred.manoeuvre and not tr.tracking_only(pred)
    best = pred.track.best()
    assert best.P[4, 4] >= before + cfg.manoeuvre_yaw_rate_sigma ** 2 - 1e-9      # the CAV's yaw rate
    assert best.P[3, 3] < cfg.manoeuvre_yaw_rate_sigma ** 2                       # not the Ego's
    assert velocity_heading_yaws(w.frame("ego", t, True), turning) is not None
    with without_heading_prior():                 # the velocities say nothing; the road axes still do
        assert velocity_heading_yaws(w.frame("ego", t, True), turning) is None
        axes = heading_yaws(w.frame("ego", t, True), turning)
        assert np.allclose(axes, heading_yaws(w.frame("ego", t, True), w.frame("cav", t, True)), atol=np.radians(2))
    assert velocity_heading_yaws(w.frame("ego", t, True), turning) is not None


def test_a_turn_is_a_manoeuvre_from_its_start_to_its_end_however_many_searches_it_takes():
    """In a steady turn the radar's velocity holds its sideways offset: the frames of the whole
    turn are manoeuvres (each searches globally) until the velocity swings back; one that lasts
    longer than manoeuvre_max_s ends, its direction the new reference (a long curve). The yaw
    rate is made uncertain only where it changes: when the turn begins and when it ends."""
    from dataclasses import replace

    w = World()
    cfg = TrackConfig(max_age_s=2.0, full_search_every=10, manoeuvre_max_s=1.0, lever_arm_m=0.0)
    tr = Tracker(cfg)

    def frame_pair(t: float, v_cav: np.ndarray) -> tuple[SharedFrame, SharedFrame]:
        return w.frame("ego", t, True), replace(w.frame("cav", t, True), ego_velocity=v_cav)

    straight, turning = w.v_cav, np.array([-1.5, 9.0])           # 9.5 deg sideways in the turn
    t = 1.0
    for _ in range(3):
        own, oth = frame_pair(t, straight)
        assert not tr.predict(own, oth).manoeuvre
        _commit(tr, own, oth, w.truth(t, t), p=0.95)
        t += 0.05
    for k in range(8):                                           # 0.4 s of steady turning
        own, oth = frame_pair(t, turning)
        before = tr.track("cav").best().P[4, 4]
        pred = tr.predict(own, oth)
        assert pred.manoeuvre and not tr.tracking_only(pred)
        loosened = pred.track.best().P[4, 4] - before >= cfg.manoeuvre_yaw_rate_sigma ** 2 - 1e-9
        assert loosened == (k == 0)                              # the CAV's yaw rate: where the turn begins
        _commit(tr, own, oth, w.truth(t, t), p=0.95)             # a full search: as in fusion
        t += 0.05
    for expected in (True, False):          # out of the turn: the yaw rate changes once more, then no more
        own, oth = frame_pair(t, straight)
        assert tr.predict(own, oth).manoeuvre == expected
        _commit(tr, own, oth, w.truth(t, t), p=0.95)
        t += 0.05
    flags = []
    for _ in range(30):                                          # 1.5 s in one long curve
        own, oth = frame_pair(t, turning)
        flags.append(tr.predict(own, oth).manoeuvre)
        _commit(tr, own, oth, w.truth(t, t), p=0.95)
        t += 0.05
    assert all(flags[:20]) and not any(flags[-5:])


def test_a_manoeuvre_settles_for_manoeuvre_hold_s_after_it_ends():
    """While a radar turns, and for manoeuvre_hold_s after the turn ends, the prediction is
    `settling` (fusion then counts every candidate as evidence: a yaw rate the turn left is not
    corrected by refinements that start at the prediction); straight driving never settles."""
    from dataclasses import replace

    w = World()
    cfg = TrackConfig(max_age_s=2.0, full_search_every=10, manoeuvre_hold_s=0.52, lever_arm_m=0.0)
    tr = Tracker(cfg)
    straight, turning = w.v_cav, np.array([-1.5, 9.0])
    flags = []
    for k, v_cav in enumerate([straight] * 3 + [turning] * 4 + [straight] * 20):
        t = 1.0 + 0.05 * k
        own, oth = w.frame("ego", t, True), replace(w.frame("cav", t, True), ego_velocity=v_cav)
        pred = tr.predict(own, oth)
        flags.append((pred.manoeuvre, pred.settling))
        _commit(tr, own, oth, w.truth(t, t), p=0.95)
    manoeuvre, settling = np.array(flags).T
    last = int(np.flatnonzero(manoeuvre).max())
    assert manoeuvre[3] and last >= 7 and not settling[:3].any()
    assert settling[3:last + 11].all() and not settling[last + 11:].any()     # 10 frames: 0.5 s


def test_through_a_turn_with_nothing_in_common_the_track_turns_as_the_sideways_velocity_says():
    """A radar lever_arm_m ahead of its rear axle moves sideways at yaw rate x lever arm: a track
    that coasts through the CAV's turn (no candidates) turns with it, its yaw rate moved towards
    v sin(offset) / lever_arm_m (weighed once against what it knew: here, where the turn began,
    two thirds of the way) instead of keeping the one it had; the Ego, going straight, keeps
    its own; off (0), the track coasts straight on. The World's backgrounds do not turn (only
    the velocity is swung), so the radars' own rotation from them is left out
    (`TrackConfig.odometry`, tests/track/test_odometry.py): the bound alone is under test."""
    from dataclasses import replace

    w = World()
    offset = np.radians(10.0)
    turning = _rot(10.0) @ w.v_cav                              # swung left: a left (CCW) turn
    rate = np.hypot(*w.v_cav) * np.sin(offset) / TrackConfig().lever_arm_m
    yaws = {}
    for arm in (TrackConfig().lever_arm_m, 0.0):
        tr = Tracker(TrackConfig(max_age_s=2.0, lever_arm_m=arm, odometry=None))
        t = _straight_start(w, tr)
        start = tr.track("cav").best().x[2]
        for _ in range(10):                                      # 0.5 s, nothing in common
            own = w.frame("ego", t, True)
            oth = replace(w.frame("cav", t, True), ego_velocity=turning)
            pred = tr.predict(own, oth)
            assert pred.turning.tolist() == [False, True]
            tr.commit(own, oth, pred, [], full_search=True)
            t += 0.05
        best = tr.track("cav").best()
        yaws[arm] = best.x[2] - start
        if arm:
            assert 0.5 * rate < best.x[4] < 1.05 * rate and abs(best.x[3]) < 0.02
    assert 0.4 * rate * 0.5 < yaws[TrackConfig().lever_arm_m] < 1.05 * rate * 0.5
    assert abs(yaws[0.0]) < 0.02


def test_a_hypothesis_born_in_a_turn_takes_the_turn_rate_and_not_its_guess_of_none():
    """A new hypothesis starts at yaw rate 0, sure of it to `yaw_rate_sigma0` (vehicles mostly
    drive straight); one born in the CAV's turn (a track re-acquired there) takes the rate the
    sideways velocity implies on the next frames instead of keeping that guess."""
    from dataclasses import replace

    w = World()
    turning = _rot(-10.0) @ w.v_cav                             # a right (clockwise) turn
    rate = -np.hypot(*w.v_cav) * np.sin(np.radians(10.0)) / TrackConfig().lever_arm_m
    tr = Tracker(TrackConfig(max_age_s=2.0))
    t = _straight_start(w, tr)
    own, oth = w.frame("ego", t, True), replace(w.frame("cav", t, True), ego_velocity=turning)
    tr.commit(own, oth, tr.predict(own, oth), [], full_search=True)
    born = _born_in_turn(w, tr, t, turning, np.diag([0.3, 0.3, np.radians(1.0)]) ** 2)
    assert len(born) == 1 and abs(born[0].x[4] - rate) < 1e-9
    bound = TrackConfig().lever_arm_spread * abs(rate) + 0.05
    assert np.sqrt(born[0].P[4, 4]) == pytest.approx(bound)
    # a garbled velocity (300 m/s, 10 deg off: 17 rad/s at 3 m) sets no rate a car cannot turn at
    born = _born_in_turn(w, tr, t + 0.1, turning * 33.0, np.diag([0.3, 0.3, np.radians(1.0)]) ** 2)
    assert born and all(abs(h.x[4]) <= MAX_YAW_RATE for h in born)


def test_a_turn_the_candidates_measure_teaches_the_track_the_radar_s_lever_arm():
    """The CAV's radar sits 2 m ahead of its axle, not the 3 m the tracker assumes: candidates
    that measure its turn teach the track that lever arm (sideways speed / yaw rate), and a
    hypothesis born later in the turn takes the turn's rate, not the two thirds of it 3 m
    implies. The World's backgrounds do not turn: the radars' own rotation is left out."""
    from dataclasses import replace

    w = World()
    offset, arm = np.radians(10.0), 2.0
    turning = _rot(10.0) @ w.v_cav
    rate = np.hypot(*w.v_cav) * np.sin(offset) / arm
    tr = Tracker(TrackConfig(max_age_s=2.0, odometry=None))
    t = _straight_start(w, tr)
    t0, cov = t, np.diag([0.2, 0.2, np.radians(0.5)]) ** 2
    for _ in range(12):                                          # 0.6 s of a measured turn
        own, oth = w.frame("ego", t, True), replace(w.frame("cav", t, True), ego_velocity=turning)
        z = pose_of(w.truth(t, t)) + [0.0, 0.0, rate * (t - t0)]
        tr.commit(own, oth, tr.predict(own, oth), [Candidate(z, cov, 0.95)], full_search=True)
        t += 0.05
    learnt = tr.track("cav").extra["lever"]
    assert np.isnan(learnt[0]) and abs(learnt[1] - arm) < 0.3
    born = _born_in_turn(w, tr, t, turning, cov)
    assert len(born) == 1 and abs(born[0].x[4] - rate) < 0.15 * rate


def test_one_fusion_remembers_the_directions_of_travel_per_heading_prior_setting():
    """The velocity angles are computed once per frame pair inside a fusion, but a block without
    the heading prior never sees the ones with it (nor the other way round)."""
    from mmatch.ego.base import velocity_heading_yaws, without_heading_prior
    from mmatch.ego.observations import observations_shared

    w = World()
    own, oth = w.frame("ego", 1.0, True), w.frame("cav", 1.0, True)
    with observations_shared():
        first = velocity_heading_yaws(own, oth)
        assert first is not None
        with without_heading_prior():
            assert velocity_heading_yaws(own, oth) is None
        np.testing.assert_array_equal(velocity_heading_yaws(own, oth), first)


def test_the_pose_filter_weighs_the_chosen_estimate_at_its_published_confidence(monkeypatch):
    """The frame's chosen estimate enters the pose filter as a single frame would publish it (the
    model's calibration), the candidates not chosen at the model's own probability; one
    unconfirmed pair below the single-pair threshold, which a frame refuses whatever its
    probability, at its own too."""
    from mmatch.ego.confidence import FEATURES, Assessment, published_confidence
    w = World()
    fuser = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0)))

    def assessment(p: float, n_pairs: float, sighting: float) -> Assessment:
        return Assessment(p, np.eye(3) * 0.01, 0.0, "poor fit",
                          dict.fromkeys(FEATURES, 0.0) | {"n_pairs": n_pairs, "sighting": sighting, "margin": 1.0})

    assert fuser._measured_confidence(assessment(0.45, 2.0, 0.0), True) == published_confidence(0.45) > 0.6
    assert fuser._measured_confidence(assessment(0.45, 1.0, 1.0), True) == published_confidence(0.45)
    assert fuser._measured_confidence(assessment(0.45, 1.0, 0.0), True) == 0.45      # one unconfirmed pair
    seen = []
    commit = fuser.tracker.commit

    def spy(own, other, pred, candidates, full_search, view=None):
        seen.append(candidates)
        return commit(own, other, pred, candidates, full_search, view)

    monkeypatch.setattr(fuser.tracker, "commit", spy)
    chosen = {}
    arbitrate = fuser._arbitrate

    def keep(own, other, match, aligned):
        out = arbitrate(own, other, match, aligned)
        chosen["a"], chosen["all"] = out[1], [a for _, a in out[2]]
        return out

    monkeypatch.setattr(fuser, "_arbitrate", keep)
    own, oth = w.frame("ego", 4.97, True), w.frame("cav", 4.95, True)
    fuser.fuse(own, oth)
    ps = [c.p for c in seen[-1]]
    k = next(i for i, a in enumerate(chosen["all"]) if a.confidence == chosen["a"].confidence)
    assert ps[k] == pytest.approx(fuser._measured_confidence(chosen["a"], True)) and ps[k] > chosen["a"].confidence
    assert [p for i, p in enumerate(ps) if i != k] == [a.confidence for i, a in enumerate(chosen["all"]) if i != k]


def test_a_hypothesis_that_overtook_an_established_rival_is_capped_by_the_rivals_belief():
    """TrackConfig.rival_memory_s: after a slide overtakes a right track that frames had
    confirmed, the slide's publication is capped by 1 - the belief the right one had, for
    rival_memory_s (the evidence that made the right one believed was of the same kind)."""
    w = World()
    tr = Tracker(TrackConfig(max_age_s=2.0))

    def slide(t: float) -> np.ndarray:
        return w.truth(t, t) @ se2_to_matrix(np.eye(2), np.array([0.0, 12.0]))

    t = _straight_start(w, tr)
    right = tr.track("cav").best()
    assert right.hits >= 3 and right.belief >= 0.9
    for _ in range(20):                              # full searches that find only a 12 m slide
        best, _ = _commit(tr, w.frame("ego", t, True), w.frame("cav", t, True), slide(t), p=0.97)
        t += 0.05
        if best.uid != right.uid:
            break
    assert best.uid != right.uid and rte_m(w.truth(t - 0.05, t - 0.05), best.T) > 10
    took_over = t - 0.05
    assert tr.rival("cav", best) >= 0.9                # the right one: 0.9+ a moment ago
    assert tr.rival("cav", tr.track("cav").best()) == tr.rival("cav", best)
    while t < took_over + 1.2:                         # a second later the slide stands alone
        best, _ = _commit(tr, w.frame("ego", t, True), w.frame("cav", t, True), slide(t), p=0.97)
        t += 0.05
    assert all(h.uid == best.uid or h.belief < 0.5 for h in tr.track("cav").hypotheses)
    assert tr.rival("cav", best) == 0.0
    off = Tracker(TrackConfig(max_age_s=2.0, rival_memory_s=0.0))
    _straight_start(w, off)
    assert off.rival("cav", new_hypothesis(np.zeros(3), np.eye(3), 0.5, off.cfg.filter)) == 0.0


def test_a_contested_track_is_refused_naming_it():
    """The Fuser publishes a track's hypothesis at no more than 1 - its rival's recent belief
    (`Tracker.rival`), and says "contested" when that alone refuses it."""
    w = World()
    fuser = Fuser(FusionConfig(track=TrackConfig(max_age_s=2.0)))
    frames = list(w.drive(4))
    for _, own, oth in frames[:3]:
        res = fuser.fuse(own, oth)
    assert res.status == "fused" and res.confidence > 0.8
    track = fuser.tracker.track("cav")
    track.beliefs.append((float(frames[2][1].stamp), -1, 0.6))   # a rival believed 0.6 just now
    res = fuser.fuse(frames[3][1], frames[3][2])
    assert res.status == "no-estimate" and res.reason == "contested"
    assert res.confidence == pytest.approx(0.4) and res.refused_T is not None


def test_remembered_beliefs_never_come_from_the_future_and_are_bounded():
    """A clock that steps back must not leave a rival belief that never ages (hostile stamps)."""
    w = World()
    tr = Tracker(TrackConfig(max_age_s=2.0))
    t = _straight_start(w, tr)                         # beliefs remembered at 1.0-1.1 s
    assert tr.track("cav").beliefs and max(s for s, _, _ in tr.track("cav").beliefs) > 1.05
    own, oth = w.frame("ego", 0.5, True), w.frame("cav", 0.5, True)
    _commit(tr, own, oth, w.truth(0.5, 0.5), p=0.95)
    track = tr.track("cav")
    assert track is not None and all(s <= 0.5 for s, _, _ in track.beliefs)
    many = Tracker(TrackConfig(max_age_s=2.0, rival_memory_s=100.0))
    t = _straight_start(w, many)
    for _ in range(MAX_BELIEF_RECORDS + 20):           # every frame remembered, 100 Hz
        own, oth = w.frame("ego", t, True), w.frame("cav", t, True)
        _commit(many, own, oth, w.truth(t, t), p=0.95)
        t += 0.01
    beliefs = many.track("cav").beliefs
    assert len(beliefs) == MAX_BELIEF_RECORDS and beliefs[-1][0] == pytest.approx(t - 0.01)
