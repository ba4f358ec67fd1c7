"""Fused object tracks: one id per vehicle across frames and across the two views, velocities
from the two radars' Doppler, the CAV's vehicles compared at the Ego's capture time."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.track.objects import ObjectTracker, centres
from mmatch.shared import SharedFrame

DT = 0.05                      # Ego frame period, s
CAV_LAG = 0.02                 # the CAV captures 20 ms after the Ego


def _rot(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _frame(sender: str, stamp: float, v_radar: np.ndarray, cars: list[tuple[np.ndarray, np.ndarray]],
           rng: np.random.Generator) -> SharedFrame:
    """A radar's SharedFrame of cars (centre, ground velocity; both in this radar's frame): a few
    points on each car's near face with the Doppler the radar would measure (DESIGN.md)."""
    pts, idx = [], []
    for k, (c, v) in enumerate(cars):
        u = c / np.linalg.norm(c)
        n = np.array([-u[1], u[0]])
        for s in np.linspace(-0.8, 0.8, 6):
            p = c - 2.2 * u + s * n + rng.normal(0, 0.05, 2)
            up = p / np.linalg.norm(p)
            pts.append([p[0], p[1], 0.0, (v - v_radar) @ up + rng.normal(0, 0.05), 20.0])
            idx.append(k)
    V = len(cars)
    return SharedFrame(sender=sender, seq=int(stamp * 1000), stamp=stamp, radar_height=1.0, ego_velocity=v_radar.copy(),
                       vehicle_points=np.array(pts, np.float32).reshape(-1, 5), vehicle_index=np.array(idx, np.int32),
                       vehicle_boxes=np.zeros((V, 6), np.float32), vehicle_box_index=np.arange(V, dtype=np.int32),
                       vehicle_centers=np.array([c for c, _ in cars], np.float32).reshape(-1, 2),
                       vehicle_features=np.zeros((V, 32), np.float32))


def test_centre_is_the_nearest_return_plus_the_near_face():
    rng = np.random.default_rng(0)
    f = _frame("e", 0.0, np.zeros(2), [(np.array([3.0, 30.0]), np.zeros(2))], rng)
    c, has = centres(f)
    assert has.all() and np.linalg.norm(c[0] - [3.0, 30.0]) < 0.3


def test_vehicles_keep_one_id_across_frames_and_views_with_two_radar_velocity():
    """The Ego drives at 10 m/s; the CAV 20 m ahead in the next lane, turned 8 deg, at 9 m/s.
    Car A (ahead of both, drifting across) only the Ego sees, car B both (paired in some frames,
    not in others), car C (oncoming) only the CAV; A hides from the Ego for 0.4 s."""
    rng = np.random.default_rng(1)
    v_ego = np.array([0.0, 10.0])
    cav_p, cav_yaw, v_cav_world = np.array([3.5, 20.0]), np.radians(8.0), _rot(np.radians(8.0)) @ np.array([0.0, 9.0])
    cars = {"A": (np.array([-3.0, 45.0]), np.array([1.0, 12.0])),
            "B": (np.array([3.5, 40.0]), np.array([-0.5, 11.0])),
            "C": (np.array([-3.0, 90.0]), np.array([0.0, -12.0]))}
    tk = ObjectTracker()
    ids = {"A": set(), "B_own": set(), "B_cav": set(), "C": set()}
    errs = {"A": [], "B": [], "C": []}
    for k in range(60):
        t = k * DT
        ego_pos = v_ego * t                                         # world = Ego radar frame at t = 0
        world = {n: (p + v * t, v) for n, (p, v) in cars.items()}
        # the Ego's view at t; the CAV's view at t + CAV_LAG, in the CAV radar's frame
        seen_a = not 30 <= k < 38
        own_cars = [(world["A"][0] - ego_pos, world["A"][1])] if seen_a else []
        own_cars.append((world["B"][0] - ego_pos, world["B"][1]))
        own = _frame("ego", t, v_ego, own_cars, rng)
        tc = t + CAV_LAG
        cav_pos = cav_p + v_cav_world * tc
        to_cav = _rot(-cav_yaw)
        cav_cars = [(to_cav @ (cars[n][0] + cars[n][1] * tc - cav_pos), to_cav @ cars[n][1]) for n in ("C", "B")]
        other = _frame("cav1", tc, to_cav @ v_cav_world, cav_cars, rng)
        T = np.eye(4)
        T[:2, :2], T[:2, 3] = _rot(cav_yaw), cav_pos - v_ego * t      # CAV radar (at tc) -> Ego radar (at t)
        b_own = 1 if seen_a else 0
        pairs = np.array([[b_own, 1]]) if k % 3 else np.zeros((0, 2), int)   # the matcher misses it at times
        of = tk.step(own, [(other, T, np.diag([0.04, 0.04, 1e-5]), pairs)])
        if seen_a:
            ids["A"].add(int(of.own_ids[0]))
        ids["B_own"].add(int(of.own_ids[b_own]))
        ids["B_cav"].add(int(of.other_ids["cav1"][1]))
        ids["C"].add(int(of.other_ids["cav1"][0]))
        if k >= 40:
            by_id = {tr.id: tr for tr in of.tracks}
            for n, key in (("A", "A"), ("B", "B_own"), ("C", "C")):
                (i,) = ids[key]
                tr = by_id[i]
                errs[n].append((np.linalg.norm(tr.x[2:] - world[n][1]), np.linalg.norm(tr.x[:2] - (world[n][0] - ego_pos))))
    assert all(len(v) == 1 for v in ids.values()), ids                    # one id each, through the gap too
    assert ids["B_own"] == ids["B_cav"]                                   # one vehicle, one id, both views
    assert len(ids["A"] | ids["B_own"] | ids["C"]) == 3
    vel = {n: np.median([e[0] for e in v]) for n, v in errs.items()}
    pos = {n: np.median([e[1] for e in v]) for n, v in errs.items()}
    assert vel["B"] < 0.2, vel                                            # two lines of sight
    assert vel["A"] < 0.5 and vel["C"] < 0.5, vel                         # one radar and the centres
    assert max(pos.values()) < 0.5, pos


def test_a_cav_view_is_predicted_to_the_ego_capture_time():
    """A car at 20 m/s seen only by the CAV 25 ms after the Ego: the track holds where the car
    was at the Ego's capture time, not where the CAV saw it."""
    rng = np.random.default_rng(2)
    tk = ObjectTracker()
    v = np.array([0.0, 20.0])
    for k in range(40):
        t = k * DT
        own = _frame("ego", t, np.zeros(2), [], rng)
        other = _frame("cav1", t + 0.025, np.zeros(2), [(np.array([2.0, 30.0]) + v * (t + 0.025), v)], rng)
        of = tk.step(own, [(other, np.eye(4), None, np.zeros((0, 2), int))])
    (tr,) = of.tracks
    truth = np.array([2.0, 30.0]) + v * t
    assert np.linalg.norm(tr.x[:2] - truth) < 0.2 < np.linalg.norm(tr.x[:2] - (truth + v * 0.025))
    assert np.linalg.norm(tr.x[2:] - v) < 0.2


def test_ids_are_not_reused_and_a_new_drive_starts_afresh():
    rng = np.random.default_rng(3)
    tk = ObjectTracker()
    seen = []
    for k in range(60):               # a car seen for 5 frames, then gone for longer than a track coasts
        t = k * DT
        cars = [(np.array([0.0, 30.0]), np.zeros(2))] if k < 5 or k > 50 else []
        of = tk.step(_frame("ego", t, np.zeros(2), cars, rng), [])
        seen += [int(i) for i in of.own_ids]
    assert seen[0] != seen[-1] and len(set(seen[:5])) == 1
    of = tk.step(_frame("ego", 0.0, np.zeros(2), [(np.array([0.0, 30.0]), np.zeros(2))], rng), [])
    assert list(of.own_ids) == [1]                                       # stamps went back: a new drive


@pytest.mark.parametrize("speed", [0.0, 15.0])
def test_the_ego_motion_is_taken_out(speed):
    """A parked car (ground velocity 0) stays a parked car while the Ego drives past it."""
    rng = np.random.default_rng(4)
    tk = ObjectTracker()
    v_ego = np.array([0.0, speed])
    for k in range(30):
        t = k * DT
        of = tk.step(_frame("ego", t, v_ego, [(np.array([-4.0, 60.0]) - v_ego * t, np.zeros(2))], rng), [])
    (tr,) = of.tracks
    assert np.linalg.norm(tr.x[2:]) < 0.3
