"""Know when the estimate is wrong: hand-made situations that defeat the evidence must end in
"no estimate" or a right answer, never a confident wrong one; covariance and eval figures."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.confidence import (CHI2_3_95, FEATURES, PairContext, features, inside_ellipse, pose_error,
                                   published_confidence, tells_poses_apart)
from mmatch.evaluate import EvalConfig, evaluate_scene, sureness_report
from mmatch.sim.scenario import scene_from_world
from mmatch.shared import SharedFrame
from mmatch.sim.world import LANE_W, Vehicles, World, _Builder

SEEDS = range(4)


def _world(cars: list[tuple[float, float]], one_side: bool = False, colour: int = 0, poles: bool = True,
           ego_speed: float = 14.0, colours: list[int] | None = None) -> World:
    """A straight 3-lane road along +y: guardrails (one side only if asked) and poles every 25 m,
    nothing else; Ego at (0, 0) driving +y at ego_speed and CAV at (0, 30) at 14 m/s, `cars`
    (x, y) at the same speed, all alike (one size; one colour unless `colours` gives each its own)."""
    b = _Builder(np.random.default_rng(0))
    half = 1.5 * LANE_W
    for side in ((1,) if one_side else (-1, 1)):
        b.guardrail((side * (half + 0.6), -450.0), (side * (half + 0.6), 450.0))
        for y in np.arange(-440.0, 450.0, 25.0) if poles else ():
            b.pole((side * (half + 1.2), y))
    pts, kind, wa, wb, occ = b.result()
    pos = np.array([[0.0, 0.0], [0.0, 30.0]] + [list(c) for c in cars])
    n = len(pos)
    speed = np.full(n, 14.0)
    speed[0] = ego_speed
    colour_of = np.array([colour, colour] + list(colours)) if colours is not None else np.full(n, colour)
    veh = Vehicles(pos0=pos, yaw=np.full(n, np.pi / 2), speed=speed,
                   size=np.tile([4.5, 1.85, 1.5], (n, 1)), colour=colour_of, parked=np.zeros(n, bool))
    return World(road="straight", lanes=3, static_pts=pts, static_kind=kind, walls_a=wa, walls_b=wb,
                 wall_occludes=occ, vehicles=veh, ego=0, cav=1, relation="same",
                 meta={"mode": "test", "road": "straight", "relation": "same"})


CASES = {
    "symmetric road, nobody shared": lambda: _world([]),
    "platoon of identical cars": lambda: _world([(LANE_W, 40.0 + 9.0 * k) for k in range(5)]),
    "one co-visible vehicle": lambda: _world([(LANE_W, 52.0)]),
    "all background on one line": lambda: _world([(-LANE_W, 55.0)], one_side=True),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_hard_situations_give_no_estimate_or_a_right_one(case):
    """Never a grossly wrong estimate (RRE > 10 deg or RTE > 5 m) let through, and "no estimate"
    or a success in at least 3 of 4 draws (the rest: a near miss, 2-5 m)."""
    outcomes, safe = [], 0
    for seed in SEEDS:
        res = evaluate_scene(scene_from_world(CASES[case](), seed, "nominal", name=case), EvalConfig())
        outcomes.append((res["status"], res["success"], res["confidence"], res["rte_m"]))
        fused = res["status"] == "fused"
        assert not (fused and (res["rte_m"] > 5 or res["rre_deg"] > 10)), (case, seed, res["rte_m"], res["rre_deg"])
        safe += (not fused) or res["success"]
    print(f"\n{case}: {outcomes}")
    assert safe >= 3, outcomes


def test_an_ego_standing_still_still_gets_estimates_and_no_wrong_one():
    """A radar standing still gives no road direction (no heading prior): the confidence model
    fit without one decides; the model fit with one refused every such frame."""
    world = lambda: _world([(LANE_W, 45.0), (-LANE_W, 58.0), (0.0, 72.0)], ego_speed=0.0, colours=[1, 3, 5])
    fused_right = 0
    for seed in SEEDS:
        scene = scene_from_world(world(), seed, "nominal", name="ego stopped")
        res = evaluate_scene(scene, EvalConfig())
        assert not (res["status"] == "fused" and not res["success"]), (seed, res["rte_m"], res["rre_deg"])
        fused_right += res["status"] == "fused"
    assert fused_right >= 2


def _line_frame(sender: str, y0: float) -> SharedFrame:
    """A frame whose only background is a guardrail 6 m to the right (every 0.8 m, 0.2 m noise)."""
    rng = np.random.default_rng(len(sender))
    y = np.arange(2.0, 80.0, 0.8)
    bg = np.column_stack([6.0 + rng.normal(0, 0.2, len(y)), y - y0 + rng.normal(0, 0.1, len(y)), np.zeros(len(y))])
    return SharedFrame(sender, 0, 0.0, 0.5, ego_velocity=np.array([0.0, 14.0]),
                       vehicle_points=np.zeros((0, 5), np.float32), vehicle_index=np.zeros(0, np.int32),
                       vehicle_boxes=np.zeros((0, 6), np.float32), vehicle_box_index=np.zeros(0, np.int32),
                       vehicle_centers=np.zeros((0, 2), np.float32), vehicle_features=np.zeros((0, 32), np.float32),
                       background=bg.astype(np.float32))


def test_covariance_is_long_along_a_street_with_one_line_of_background():
    own, other = _line_frame("ego", 0.0), _line_frame("cav", 30.0)     # the CAV 30 m ahead
    R, t = np.eye(2)[None], np.array([[0.0, 30.0]])
    X, cov, _ = features(PairContext(own, other), R, t, np.zeros((0, 2), int))
    w, v = np.linalg.eigh(cov[0][:2, :2])
    assert abs(v[1, 1]) > 0.99                      # the loosest direction runs along the road (+y)
    assert np.sqrt(w[1]) > 20 * np.sqrt(w[0]) and np.sqrt(w[0]) < 0.1
    feats = dict(zip(FEATURES, X[0]))
    assert feats["bg_linearity"] < 0.01 and feats["n_pairs"] == 0


def test_ellipse_and_error_conventions():
    T_gt, T = np.eye(4), np.eye(4)
    T[:2, 3] = [2.0, -2.0]
    a = np.radians(3.0)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    e = pose_error(T_gt, T)
    assert np.allclose(e, [2.0, -2.0, a])
    cov = np.diag([1.0, 1.0, np.radians(2.0) ** 2])
    assert e @ np.linalg.solve(cov, e) > CHI2_3_95 and not inside_ellipse(e, cov)
    assert inside_ellipse(e, cov * 4)


def test_eval_reports_coverage_gross_rate_calibration_and_risk_coverage():
    def row(conf, success, gross, inside, emitted=True):
        return {"status": "fused" if emitted else "no-estimate", "confidence": conf, "success": success and emitted,
                "candidate": {"success": success, "gross": gross, "inside_95": inside, "emitted": emitted}}
    rows = [row(0.9, True, False, True), row(0.8, True, False, False), row(0.7, False, True, False),
            row(0.2, False, True, False, emitted=False), {"status": "no-estimate", "confidence": None}]
    rep = sureness_report(rows)
    assert rep["coverage"] == pytest.approx(3 / 5) and rep["gross_rate"] == pytest.approx(1 / 3)
    assert rep["calibration"] == pytest.approx(1 / 3)
    curve = {x["coverage"]: x for x in rep["risk_coverage"]}
    assert set(curve) == {0.5, 0.6, 0.7, 0.8}      # 4 candidates among 5 scenes: up to 0.8
    assert curve[0.6]["gross_rate"] == pytest.approx(1 / 3) and curve[0.8]["gross_rate"] == pytest.approx(0.5)
    # reliability over the four rated candidates: bins 0.2 (0 right), 0.7 (0), 0.8 (1), 0.9 (1)
    rel = rep["reliability"]
    assert [b["n"] for b in rel["bins"]] == [1, 1, 1, 1]
    assert rel["ece"] == pytest.approx((0.2 + 0.7 + 0.2 + 0.1) / 4)
    assert rel["brier"] == pytest.approx((0.2 ** 2 + 0.7 ** 2 + 0.2 ** 2 + 0.1 ** 2) / 4)


def _calibrated(a: float = 1.1, b: float = 1.6):
    from dataclasses import replace

    from mmatch.ego.confidence import load_model
    return replace(load_model(), calibration=(a, b))


def test_published_confidence_is_a_monotone_map_of_the_models_probability():
    from mmatch.ego.confidence import ProbabilityModel
    from mmatch.errors import ConfigError
    model = _calibrated()
    p = np.linspace(0.0, 1.0, 101)
    q = model.published(p)
    assert q[0] == 0.0 and q[-1] == 1.0 and np.all(np.diff(q) > 0)      # order and the ends kept
    assert np.all(q[1:-1] > p[1:-1])                                     # b > 0: surer than the raw model
    assert model.published(0.5) == pytest.approx(1 / (1 + np.exp(-1.6)))
    np.testing.assert_allclose([model.raw(x) for x in q[1:-1]], p[1:-1], atol=1e-9)
    assert model.raw(0.0) == 0.0 and model.raw(1.0) == 1.0
    again = ProbabilityModel.from_json(model.to_json())
    assert again.calibration == pytest.approx(model.calibration)
    assert _calibrated().published(0.3) == again.published(0.3)
    import json
    d = json.loads(model.to_json())
    for bad in ({"a": 0.0, "b": 1.0}, {"a": 1.0, "b": float("nan")}, {"a": 1.0}):
        d["calibration"] = bad
        with pytest.raises(ConfigError, match="calibration|not a confidence model"):
            ProbabilityModel.from_dict(d, "m.json")


@pytest.mark.parametrize("raw, configured, status", [
    (0.03, None, "fused"),          # the fitted threshold reads the raw probability (raw: above it)
    (-0.02, None, "no-estimate"),   # ... and below it
    (0.45, "above", "no-estimate"),  # a configured threshold is in published units
    (0.55, "above", "fused"),
])
def test_a_frame_is_published_with_the_calibrated_confidence_and_gated_as_before(monkeypatch, tmp_path, raw,
                                                                                   configured, status):
    from mmatch.ego import confidence
    from mmatch.ego.base import velocity_heading_yaws
    from mmatch.ego.confidence import Assessment, ConfidenceConfig
    from mmatch.fusion import FusionConfig, Fuser
    from mmatch.label_frames import shared_from_labels
    model = _calibrated()
    if not configured:
        raw = model.threshold + raw
    path = tmp_path / "calibrated.json"
    path.write_text(model.to_json())
    thr = float(model.published(0.5)) if configured else None        # published 0.5 of the raw model
    cfg = ConfidenceConfig(model_path=str(path), threshold=thr)
    assert confidence.threshold(cfg) == pytest.approx(0.5 if configured else model.threshold)
    scene = scene_from_world(CASES["one co-visible vehicle"](), 0, "nominal", name="one")
    fuser = Fuser(FusionConfig(confidence=cfg))

    def arbitrate(own, other, match, aligned):
        a = Assessment(raw, np.eye(3) * 0.01, 0.0, "poor fit",
                       dict.fromkeys(FEATURES, 0.0) | {"n_pairs": 3.0, "sighting": 1.0, "margin": 1.0})
        return aligned.T, a, [(aligned.T, a)], np.zeros((0, 2), np.int32)

    monkeypatch.setattr(fuser, "_arbitrate", arbitrate)
    own, other = shared_from_labels(scene.ego, "ego"), shared_from_labels(scene.cav, "cav")
    assert velocity_heading_yaws(own, other) is not None               # the first model's frame pair
    res = fuser.fuse(own, other)
    assert res.status == status, res.reason
    assert res.confidence == pytest.approx(model.published(raw)) and res.confidence > raw
    assert res.candidates[0][1].confidence == raw                     # the arbiter's own stays raw


def _seen_from(sender: str, at: np.ndarray, v_radar: np.ndarray, v_target: np.ndarray,
               points: int = 4) -> SharedFrame:
    """A frame of one vehicle centred at `at` (radar frame, m) driving at v_target, seen by a
    radar moving at v_radar: `points` returns across its rear face 1.2 m nearer, each with the
    Doppler (v_target - v_radar) along its ray."""
    p = np.column_stack([at[0] + np.linspace(-0.6, 0.6, points), np.full(points, at[1] - 1.2), np.zeros(points)])
    u = p[:, :2] / np.linalg.norm(p[:, :2], axis=1, keepdims=True)
    pts = np.column_stack([p, u @ (v_target - v_radar), np.full(points, 20.0)]).astype(np.float32)
    return SharedFrame(sender, 0, 0.0, 0.5, ego_velocity=v_radar, vehicle_points=pts,
                       vehicle_index=np.zeros(points, np.int32),
                       vehicle_boxes=np.array([[600, 300, 680, 360, 0.9, float(np.hypot(*at))]], np.float32),
                       vehicle_box_index=np.zeros(1, np.int32), vehicle_centers=np.array([at], np.float32),
                       vehicle_features=np.zeros((1, 32), np.float32))


def _platoon_frames(ego_speed: float, points: int = 4) -> tuple[SharedFrame, SharedFrame]:
    """An Ego with no detections and a CAV (12 m/s, +y) that sees one vehicle 15 m ahead driving
    at 15 m/s (`points` returns)."""
    other = _seen_from("cav", np.array([0.0, 15.0]), np.array([0.0, 12.0]), np.array([0.0, 15.0]), points)
    return SharedFrame("ego", 0, 0.0, 0.5, ego_velocity=np.array([0.0, ego_speed])), other


@pytest.mark.parametrize("ego_speed, points, conflict",
                         [(15.0, 4, 0.0), (10.0, 4, 1.0), (10.0, 2, 0.0), (float("nan"), 4, 0.0)])
def test_a_sighting_moving_otherwise_than_the_other_radar_is_a_conflict(ego_speed, points, conflict):
    # the hypothesis puts the CAV 17.3 m behind the Ego: the CAV should then see the Ego's body
    # 15 m ahead, where it does see a vehicle; that vehicle drives at 15 m/s
    own, other = _platoon_frames(ego_speed, points)
    X, _, _ = features(PairContext(own, other), np.eye(2)[None], np.array([[0.0, -17.3]]), np.zeros((0, 2), int))
    feats = dict(zip(FEATURES, X[0]))
    assert feats["sighting"] == 1.0                 # something is there (position only)
    assert feats["sighting_conflict"] == conflict   # judged by speed from three returns on, when
    assert np.isfinite(X).all()                     # the Ego's own velocity is known


@pytest.mark.parametrize("x, sighting", [(0.0, 0.0), (10.0, -1.0)])
def test_the_other_radar_hidden_behind_a_nearer_vehicle_is_not_counted_unseen(x, sighting):
    # the hypothesis puts the Ego's body 30 m ahead of the CAV: straight behind the vehicle the
    # CAV sees at 15 m (hidden: no verdict) or 10 m to the side of it (in clear view, not seen)
    own, other = _platoon_frames(12.0)
    X, _, _ = features(PairContext(own, other), np.eye(2)[None], np.array([[-x, -32.3]]), np.zeros((0, 2), int))
    assert dict(zip(FEATURES, X[0]))["sighting"] == sighting


@pytest.mark.parametrize("yaw_deg, x, y, overlap", [
    (0, 0.0, 1.0, True),        # 1 m ahead, same heading: its body on our bonnet
    (0, 0.0, 4.0, False),       # 4 m ahead: its body ends 0.5 m before our radar
    (0, 2.0, 0.0, False),       # side by side, 2 m apart
    (0, 0.0, -3.4, True),       # its radar inside our body
    (180, 0.0, -2.0, True),     # facing us, its front inside our body
    (90, 0.0, -6.0, False),     # crossing 6 m behind our radar
    (45, 1.0, -1.0, True),      # turned, a rear corner across our side
    (45, 1.5, -1.0, False),     # ... 0.2 m clear of it
])
def test_a_pose_that_lays_the_two_bodies_on_each_other_is_impossible(yaw_deg, x, y, overlap):
    from mmatch.ego.confidence import bodies_overlap
    from mmatch.ego.rigid import rot2
    got = bodies_overlap(rot2(np.radians([yaw_deg, 0.0])), np.array([[x, y], [0.0, 30.0]]))
    assert got.tolist() == [overlap, False]


def test_an_impossible_pose_has_probability_zero_whatever_its_evidence():
    from mmatch.ego.confidence import assess_many
    from mmatch.label_frames import shared_from_labels
    from mmatch.ego.rigid import rot2
    scene = scene_from_world(CASES["one co-visible vehicle"](), 0, "nominal", name="one")
    own, other = shared_from_labels(scene.ego, "ego"), shared_from_labels(scene.cav, "cav")
    T = scene.gt_T_ego_cav
    R = np.stack([T[:2, :2], rot2(np.array(0.0))])
    t = np.stack([T[:2, 3], np.array([0.0, 1.0])])               # the truth, and 1 m ahead of us
    right, impossible = assess_many(PairContext(own, other), R, t, np.zeros((0, 2), int))
    assert right.confidence > 0.5 and impossible.confidence == 0.0 and impossible.choice == 0.0
    assert impossible.reason == "poor fit"


def test_a_pose_that_turns_the_shared_vehicles_velocity_off_the_road_is_marked():
    # Ego and CAV side by side, both at 10 m/s along +y; a car ahead between them at 15 m/s:
    # the two radial speeds solve to its velocity only under the right rotation
    v_radar, v_car = np.array([0.0, 10.0]), np.array([0.0, 15.0])
    own = _seen_from("ego", np.array([5.0, 20.0]), v_radar, v_car)
    other = _seen_from("cav", np.array([-5.0, 20.0]), v_radar, v_car)
    rot = lambda deg: np.array([[np.cos(np.radians(deg)), -np.sin(np.radians(deg))],
                                [np.sin(np.radians(deg)), np.cos(np.radians(deg))]])
    R = np.stack([rot(0.0), rot(40.0)])
    X, _, _ = features(PairContext(own, other), R, np.array([[10.0, 0.0], [10.0, 0.0]]), np.array([[0, 0]]))
    off = X[:, FEATURES.index("doppler_heading_deg")]
    assert X[0, FEATURES.index("doppler_tested")] == 1.0
    assert off[0] < 1.0 and off[1] > 15.0, off          # half the turn: the CAV's own heading turns too


@pytest.mark.parametrize("cav_y, cav_sees, missed", [(-5.0, None, 1.0), (30.0, None, 0.0), (-5.0, 8.0, 0.0),
                                                     (-5.0, 14.0, 1.0), (-5.0, 25.0, 0.0),
                                                     (-50.0, None, 0.0)])
def test_a_vehicle_the_other_should_see_and_does_not_is_counted(cav_y, cav_sees, missed):
    # the Ego sees a car 20 m ahead; the hypothesis puts the CAV cav_y along the road, looking the
    # same way: 5 m behind the Ego the car is 25 m ahead of the CAV, well in its view; past the
    # car (30 m) or beyond its camera's reach (70 m) nothing is expected; a car the CAV sees 8 m
    # ahead hides it (and is too near the Ego's radar to count), one 14 m ahead hides it too but
    # stands 9 m ahead of the Ego, which does not see it; one 25 m ahead is the same car
    v = np.array([0.0, 12.0])
    own = _seen_from("ego", np.array([0.0, 20.0]), v, v)
    other = _seen_from("cav", np.array([0.0, cav_sees]), v, v) if cav_sees is not None else \
        SharedFrame("cav", 0, 0.0, 0.5, ego_velocity=v)
    X, _, _ = features(PairContext(own, other), np.eye(2)[None], np.array([[0.0, cav_y]]), np.zeros((0, 2), int))
    assert dict(zip(FEATURES, X[0]))["covisible_missed"] == missed


@pytest.mark.parametrize("n_pairs, sighting, confidence, threshold, published, status", [
    (1, 0, 0.65, None, 1, "no-estimate"),     # one unconfirmed pair, sure by the model: not enough
    (0, -1, 0.70, None, 0, "no-estimate"),
    (1, 1, 0.65, None, 1, "fused"),           # the other vehicle seen where the estimate puts it
    (2, 0, 0.65, None, 2, "fused"),           # two pairs
    (1, 0, 0.80, None, 1, "fused"),           # above the single-pair threshold
    (1, 0, 0.65, 0.0, 1, "fused"),            # threshold 0 emits everything
    (1, 0, 0.65, None, 2, "fused"),           # weighed on one pair, but its transform implies two
    (1, -1, 0.65, None, 3, "no-estimate"),    # ... where the other vehicle should be seen, is not
])
def test_an_estimate_on_one_unconfirmed_pair_needs_the_single_pair_threshold(
        monkeypatch, n_pairs, sighting, confidence, threshold, published, status):
    from mmatch.ego.confidence import Assessment, ConfidenceConfig
    from mmatch.fusion import FusionConfig, Fuser
    from mmatch.label_frames import shared_from_labels
    scene = scene_from_world(CASES["one co-visible vehicle"](), 0, "nominal", name="one")
    fuser = Fuser(FusionConfig(confidence=ConfidenceConfig(threshold=threshold)))
    assert fuser._threshold < 0.65 and ConfidenceConfig().single_pair_threshold == 0.75

    def arbitrate(own, other, match, aligned):
        a = Assessment(confidence, np.eye(3) * 0.01, 0.0, "poor fit",
                       dict.fromkeys(FEATURES, 0.0) | {"n_pairs": float(n_pairs), "sighting": float(sighting),
                                                       "margin": 1.0})
        # the published pairs: their count matters here, not which vehicles they are
        return aligned.T, a, [(aligned.T, a)], np.zeros((published, 2), np.int32)

    monkeypatch.setattr(fuser, "_arbitrate", arbitrate)
    res = fuser.fuse(shared_from_labels(scene.ego, "ego"), shared_from_labels(scene.cav, "cav"))
    assert res.status == status, res.reason
    assert len(res.pairs) == published
    thr = published_confidence(fuser._threshold)
    if status == "no-estimate":
        assert res.reason == "too few vehicles" and res.refused_T is not None
        # refused by the single-pair gate: published below the threshold, in proportion
        assert res.confidence == pytest.approx(published_confidence(confidence * fuser._threshold / 0.75))
        assert res.confidence < thr
    else:
        assert res.confidence == pytest.approx(published_confidence(confidence)) and res.confidence >= thr


@pytest.mark.parametrize("min_margin, margin, status", [
    (None, -2.0, "fused"),                 # default: the margin weighs in the probability only
    (0.0, -2.0, "no-estimate"),            # a gate: the matcher's own evidence prefers another pose
    (0.0, 0.5, "fused"),
])
def test_the_margin_gate_is_off_unless_configured(monkeypatch, min_margin, margin, status):
    from mmatch.ego.confidence import Assessment, ConfidenceConfig
    from mmatch.fusion import FusionConfig, Fuser
    from mmatch.label_frames import shared_from_labels
    scene = scene_from_world(CASES["one co-visible vehicle"](), 0, "nominal", name="one")
    fuser = Fuser(FusionConfig(confidence=ConfidenceConfig(min_margin=min_margin)))
    assert ConfidenceConfig().min_margin is None

    def arbitrate(own, other, match, aligned):
        a = Assessment(0.9, np.eye(3) * 0.01, 0.0, "poor fit",
                       dict.fromkeys(FEATURES, 0.0) | {"n_pairs": 3.0, "sighting": 1.0, "margin": margin})
        return aligned.T, a, [(aligned.T, a)], np.zeros((0, 2), np.int32)

    monkeypatch.setattr(fuser, "_arbitrate", arbitrate)
    res = fuser.fuse(shared_from_labels(scene.ego, "ego"), shared_from_labels(scene.cav, "cav"))
    assert res.status == status, res.reason
    if status == "no-estimate":
        assert res.reason == "ambiguous"
        assert res.confidence == pytest.approx(published_confidence(0.9 * fuser._threshold))
    assert (res.confidence >= published_confidence(fuser._threshold)) == (status == "fused")


def test_a_track_is_published_at_its_own_threshold_unless_one_is_set():
    from mmatch.ego.confidence import ConfidenceConfig, load_model, threshold
    model = load_model()
    assert threshold() == pytest.approx(model.threshold)
    assert threshold(tracked=True) == 0.6 != threshold()
    assert threshold(ConfidenceConfig(track_threshold=None), tracked=True) == threshold()
    assert threshold(ConfidenceConfig(threshold=0.0), tracked=True) == 0.0     # emit everything


def test_a_frame_another_gate_refused_publishes_below_the_threshold_in_order():
    from mmatch.ego.confidence import ConfidenceConfig, refused_probability
    cfg = ConfidenceConfig()
    assert refused_probability(0.9, None, 0.33) == 0.9 and refused_probability(0.2, "threshold", 0.33) == 0.2
    lone = [refused_probability(p, "too few vehicles", 0.33, cfg) for p in (0.2, 0.5, 0.74)]
    assert lone == pytest.approx([0.2 * 0.44, 0.5 * 0.44, 0.74 * 0.44]) and lone == sorted(lone)
    assert max(lone) < 0.33
    assert refused_probability(1.0, "ambiguous", 0.33, cfg) < 0.33 < refused_probability(0.9, None, 0.33)
    assert np.isnan(refused_probability(float("nan"), "ambiguous", 0.33, cfg))


def test_refusal_names_the_gate_a_single_frame_fails():
    from mmatch.ego.confidence import ConfidenceConfig, refusal
    two = {"n_pairs": 2.0, "sighting": 0.0, "margin": -1.0}
    lone = {"n_pairs": 1.0, "sighting": 0.0, "margin": 1.0}
    assert refusal(0.30, two, 0.42) == "threshold"
    assert refusal(0.50, two, 0.42) is None                        # no margin gate by default
    assert refusal(0.50, two, 0.42, ConfidenceConfig(min_margin=0.0)) == "ambiguous"
    assert refusal(0.50, lone, 0.42) == "too few vehicles"         # below the single-pair 0.75
    assert refusal(0.80, lone, 0.42) is None
    assert refusal(0.50, dict(lone, sighting=1.0), 0.42) is None    # the other vehicle seen where it should be
    assert refusal(0.01, lone, 0.0) is None                        # threshold 0 emits everything
    # weighed on one pair, but the transform lays two or more onto each other (published pairs)
    assert refusal(0.50, lone, 0.42, published_pairs=2) is None
    assert refusal(0.50, lone, 0.42, published_pairs=1) == "too few vehicles"
    assert refusal(0.50, dict(lone, sighting=-1.0), 0.42, published_pairs=3) == "too few vehicles"


def test_the_gated_threshold_holds_the_gross_rate_in_every_family():
    from mmatch.ego.confidence_fit import gated_threshold

    def scene(conf, gross, n_pairs=2.0, predicted=None):
        return {"confidence": conf, "evidence": {"n_pairs": n_pairs, "sighting": 0.0},
                "candidate": {"gross": gross, "success": not gross}, "predicted": predicted}
    wide = [scene(0.9, False)] * 8 + [scene(0.5, True), scene(0.6, False)]
    harsh = [scene(0.8, False)] * 4 + [scene(0.65, True)]
    thr, per = gated_threshold([wide, harsh], 0.0)
    assert thr == pytest.approx(0.66)                               # above both gross estimates
    assert per[0] == pytest.approx({"emitted": 0.8, "success": 0.8, "gross": 0.0})
    assert per[1]["emitted"] == pytest.approx(0.8) and per[1]["gross"] == 0.0
    assert gated_threshold([wide], 0.0)[0] == pytest.approx(0.51)
    # a lone unconfirmed pair is refused below the single-pair threshold whatever the threshold
    lone = [scene(0.7, True, n_pairs=1.0)] + [scene(0.6, False)] * 3
    assert gated_threshold([lone], 0.0)[0] == pytest.approx(0.01)
    # ... unless its transform implies two pairs (the scene's published ones): then the threshold
    implied = [scene(0.7, True, n_pairs=1.0, predicted=2)] + [scene(0.6, False)] * 3
    assert gated_threshold([implied], 0.0)[0] == pytest.approx(0.71)
    thr, per = gated_threshold([[scene(0.9, True)]], 0.0)           # only emitting nothing holds
    assert thr == pytest.approx(0.91) and per == [{"emitted": 0.0, "success": 0.0, "gross": 0.0}]


def test_rmnet_evidence_is_higher_at_the_truth_than_at_a_slide(hard_dir):
    """RM-net scores pairs knowing nothing of the pose: at the true transform its assignment
    finds partners it calls alike; slid 15 m along or across, the same network finds fewer and
    weaker ones (rmnet_support), on most scenes and on the sum."""
    from mmatch.label_frames import shared_from_labels
    from mmatch.scene_io import load_scene
    k = FEATURES.index("rmnet_support")
    at_truth, slid, better = 0.0, 0.0, 0
    files = sorted(hard_dir.glob("*.npz"))
    for f in files:
        s = load_scene(f)
        own, other = shared_from_labels(s.ego, "ego"), shared_from_labels(s.cav, "cav")
        T = s.gt_T_ego_cav
        R = np.stack([T[:2, :2]] * 5)
        t = T[:2, 3] + np.array([[0.0, 0.0], [0.0, 15.0], [0.0, -15.0], [15.0, 0.0], [-15.0, 0.0]])
        X, _, _ = features(PairContext(own, other), R, t, np.zeros((0, 2), int))
        at_truth += X[0, k]
        slid += X[1:, k].max()
        better += X[0, k] > X[1:, k].max()
    assert better >= 0.75 * len(files), better
    assert at_truth > 1.5 * slid, (at_truth, slid)


def test_the_chooser_picks_among_candidates_and_the_average_rates_the_choice(hard_dir):
    """The arbiter picks the candidate the packaged model's chooser prefers, and the published
    confidence is that candidate's mean of the regression's and the trees' probabilities, as the
    model's calibration publishes it."""
    from mmatch.ego.base import velocity_heading_yaws
    from mmatch.evaluate import prepare_scene
    from mmatch.fusion import Fuser, FusionConfig
    from mmatch.scene_io import load_scene

    fuser = Fuser(FusionConfig())
    differ = 0
    for f in sorted(hard_dir.glob("*.npz"))[:8]:
        own, received, _, _ = prepare_scene(load_scene(f))
        res = fuser.fuse(own, received)
        if len(res.candidates) < 2:
            continue
        choice = np.array([a.choice for _, a in res.candidates])
        conf = np.array([a.confidence for _, a in res.candidates])
        k = int(np.argmax(choice))
        T = res.T_ego_cav if res.T_ego_cav is not None else res.refused_T
        np.testing.assert_allclose(T, res.candidates[k][0])
        heading = velocity_heading_yaws(own, received) is not None
        assert res.confidence == pytest.approx(published_confidence(conf[k], heading=heading))
        assert res.confidence > conf[k] and np.all((conf >= 0) & (conf <= 1))
        differ += int(not np.allclose(choice, conf))
    assert differ >= 1


def test_fit_calibration_recovers_the_map_and_reliability_measures_it():
    from mmatch.ego.confidence_fit import fit_calibration
    from mmatch.metrics import reliability
    rng = np.random.default_rng(3)
    p = rng.uniform(0.02, 0.98, 20000)
    z = 1.2 * np.log(p / (1 - p)) + 1.5
    y = rng.random(len(p)) < 1 / (1 + np.exp(-z))
    a, b = fit_calibration(p, y)
    assert a == pytest.approx(1.2, abs=0.08) and b == pytest.approx(1.5, abs=0.08)
    before, after = reliability(p, y), reliability(_calibrated(a, b).published(p), y)
    assert before["ece"] > 0.15 and after["ece"] < 0.02 and after["brier"] < before["brier"]
    assert sum(x["n"] for x in after["bins"]) == len(p)
    with pytest.raises(ValueError, match="both outcomes"):
        fit_calibration(p[:100], np.ones(100, bool))
    # confidences at the very ends (a tracker's 0 and 1) with mixed outcomes: a finite, damped fit
    ends = np.r_[np.zeros(70), np.ones(4000), rng.uniform(0.3, 0.7, 200)]
    right = np.r_[rng.random(70) < 0.67, np.ones(4000, bool), rng.random(200) < 0.8]
    a, b = fit_calibration(ends, right)
    assert 0 < a < 1 and 0 < b < 5


def test_an_estimate_tells_poses_apart_by_two_pairs_a_sighting_or_its_own_sureness():
    assert tells_poses_apart({"n_pairs": 2.0, "sighting": 0.0}, 0.1)
    assert tells_poses_apart({"n_pairs": 1.0, "sighting": 1.0}, 0.1)
    assert tells_poses_apart({"n_pairs": 1.0, "sighting": 0.0}, 0.5)
    assert not tells_poses_apart({"n_pairs": 1.0, "sighting": 0.0}, 0.49)
    assert not tells_poses_apart({"n_pairs": 0.0, "sighting": -1.0}, 0.2)     # the background alone
    assert tells_poses_apart({}, 0.1)                 # nothing known of its evidence: as before


def test_traffic_no_box_holds_agrees_under_the_right_pose_only():
    """The moving returns both radars see (the shared vehicles' and the moving sketch of those
    no camera boxed) land on each other under the right pose; slid along the street by a car
    gap, or turned half round, they land on nothing (moving_agreement)."""
    v = np.array([0.0, 12.0])
    traffic = np.array([[-3.5, 35.0], [3.5, 48.0], [0.0, 60.0], [-3.5, 75.0]])   # Ego frame, no box
    def view(sender, at):
        f = SharedFrame(sender, 0, 0.0, 0.5, ego_velocity=v)
        f.moving = np.vstack([p - at + d for p in traffic for d in ((0, 0), (0.6, 0.3))]).astype(np.float32)
        return f
    own, other = view("ego", np.zeros(2)), view("cav", np.array([0.0, 20.0]))
    half = np.array([[-1.0, 0.0], [0.0, -1.0]])
    R = np.stack([np.eye(2), np.eye(2), half])
    t = np.array([[0.0, 20.0], [0.0, 28.0], [0.0, 20.0]])
    X, _, _ = features(PairContext(own, other), R, t, np.zeros((0, 2), int))
    agree = X[:, FEATURES.index("moving_agreement")]
    assert agree[0] == 1.0 and agree[1] < 0.2 and agree[2] < 0.2, agree
    quiet = SharedFrame("cav", 0, 0.0, 0.5, ego_velocity=v)                  # a version-2 sender: no sketch
    X, _, _ = features(PairContext(own, quiet), R[:1], t[:1], np.zeros((0, 2), int))
    assert X[0, FEATURES.index("moving_agreement")] == 0.0
