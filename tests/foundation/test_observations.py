"""Line-of-sight covariances, two-estimate distances and the Gauss-Newton refinement."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.base import FAR_SIDE, FarSideModel, MatchContext, far_side_centres
from mmatch.ego.observations import ObservationModel, mahalanobis, observe
from mmatch.ego.refine import refine
from mmatch.ego.registry import get_aligner, get_matcher
from mmatch.label_frames import shared_from_labels
from mmatch.metrics import pair_counts, rre_deg, rte_m
from mmatch.scene_io import load_scene
from mmatch.shared import SharedFrame


def _rot(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _frame(centres_pts: list, cams: np.ndarray, bg: np.ndarray | None = None) -> SharedFrame:
    """Vehicles with one radar point each at `centres_pts` (None: no point), camera centres `cams`;
    boxes twice as wide as tall (a far-side shift of about 1.2 m, FarSideModel)."""
    pts, idx = [], []
    for v, c in enumerate(centres_pts):
        if c is not None:
            pts.append([c[0], c[1], 0.0, 0.0, 10.0])
            idx.append(v)
    V = len(cams)
    return SharedFrame("x", 0, 0.0, 0.5, ego_velocity=np.array([0.0, 10.0]),
                       vehicle_points=np.array(pts, np.float32).reshape(-1, 5),
                       vehicle_index=np.array(idx, np.int32),
                       vehicle_boxes=np.tile(np.array([0, 0, 20, 10, 0.9, 20], np.float32), (V, 1)),
                       vehicle_box_index=np.arange(V, dtype=np.int32),
                       vehicle_centers=np.asarray(cams, np.float32).reshape(-1, 2),
                       vehicle_features=np.full((V, 32), 1 / 16, np.float32),
                       background=np.zeros((0, 3), np.float32) if bg is None else bg.astype(np.float32))


def test_covariance_is_long_along_the_line_of_sight():
    m = ObservationModel(camera_bearing=False)
    frame = _frame([[0.0, 30.0], None], np.array([[0.0, 31.0], [30.0, 0.0]]))
    obs = observe(frame, m)
    w, v = np.linalg.eigh(obs.cov[0])                  # vehicle with points, straight ahead
    assert np.sqrt(w[1]) == pytest.approx(m.along_points_m) and abs(v[1, 1]) == pytest.approx(1.0)
    assert np.sqrt(w[0]) == pytest.approx(m.across_m + m.across_rad * (30.0 + FAR_SIDE.shifts(frame)[0]), rel=1e-3)
    w, v = np.linalg.eigh(obs.cov[1])                  # camera only, to the right: depth error
    assert np.sqrt(w[1]) == pytest.approx(m.along_depth_m + m.along_depth_rel * 30.0)
    assert abs(v[0, 1]) == pytest.approx(1.0)
    assert obs.cam_penalty.tolist() == [m.camera_penalty, 0.0]


def test_returns_spread_beyond_a_car_length_loosen_the_centre_along_the_ray():
    """A box holding returns 9 m apart in range (another vehicle's, or the background behind it)
    knows its centre along the ray less well; within a car's length nothing changes."""
    m = ObservationModel(camera_bearing=False)
    one = _frame([[0.0, 30.0]], np.array([[0.0, 31.0]]))
    spread = SharedFrame("x", 0, 0.0, 0.5, ego_velocity=np.array([0.0, 10.0]),
                         vehicle_points=np.array([[0, 26, 0, 0, 10], [0, 35, 0, 0, 10], [0, 30, 0, 0, 10],
                                                  [20, 1, 0, 0, 10], [20, 4, 0, 0, 10]], np.float32),
                         vehicle_index=np.array([0, 0, 0, 1, 1], np.int32),
                         vehicle_boxes=np.tile(np.array([0, 0, 20, 10, 0.9, 20], np.float32), (2, 1)),
                         vehicle_box_index=np.arange(2, dtype=np.int32),
                         vehicle_centers=np.array([[0, 31], [20, 3]], np.float32),
                         vehicle_features=np.full((2, 32), 1 / 16, np.float32),
                         background=np.zeros((0, 3), np.float32))
    along = lambda cov, u: float(np.sqrt(u @ cov @ u))                       # noqa: E731
    a = observe(spread, m)
    assert along(a.cov[0], np.array([0.0, 1.0])) == pytest.approx(np.hypot(m.along_points_m, 9.0 - 5.0), rel=1e-3)
    u = np.array([20.0, 2.5]) / np.hypot(20.0, 2.5)
    assert along(a.cov[1], u) == pytest.approx(m.along_points_m, rel=1e-2)       # 3 m: a car
    assert along(observe(one, m).cov[0], np.array([0.0, 1.0])) == pytest.approx(m.along_points_m)
    off = observe(spread, ObservationModel(camera_bearing=False, along_spread_k=0.0))
    assert along(off.cov[0], np.array([0.0, 1.0])) == pytest.approx(m.along_points_m, rel=1e-3)
    bearing = observe(spread, ObservationModel())                             # on the camera's ray too
    assert along(bearing.cov[0], np.array([0.0, 1.0])) > 3.5


def test_two_end_on_views_from_crossing_directions_agree_only_where_their_rays_cross():
    # a bus at (10, 30) in the Ego frame; the Ego sees its near face 4.4 m short along its
    # ray (3 m after the far-side correction); the CAV (turned 90 deg, 20 m to the right)
    # sees its own near face as far short
    truth = np.array([10.0, 30.0])
    T_R, T_t = _rot(90), np.array([20.0, 10.0])
    in_cav = _rot(90).T @ (truth - T_t)
    near_own = truth - 4.4 * truth / np.linalg.norm(truth)
    near_cav = in_cav - 4.4 * in_cav / np.linalg.norm(in_cav)
    radar_only = ObservationModel(camera_bearing=False)
    A = observe(_frame([near_own], truth[None]), radar_only)
    B = observe(_frame([near_cav], in_cav[None]), radar_only)
    right = mahalanobis(A, B, T_R[None], T_t[None])[0, 0, 0]
    iso = np.linalg.norm(A.centres[0] - (T_R @ B.centres[0] + T_t))
    assert iso > 2.0 and right < 2.0                    # isotropically 2+ m apart, yet consistent
    print(f"\nend-on views: {iso:.2f} m apart, Mahalanobis {right:.2f}")
    wrong = mahalanobis(A, B, T_R[None], (T_t + T_R @ [0.0, 0.0] + np.array([4.0, -4.0]))[None])[0, 0, 0]
    assert wrong > 2.5                                   # beyond the pair gate: a 5.7 m shift is not


def test_the_camera_bearing_places_a_vehicle_with_points_across_its_ray():
    m = ObservationModel()
    cam = np.array([[8.0, 40.0]])                        # the box's centre estimate
    origin = np.array([0.0, -m.camera_back_m])
    ray = (cam[0] - origin) / np.linalg.norm(cam[0] - origin)
    normal = np.array([-ray[1], ray[0]])
    pts = cam[0] - 2.0 * ray + 1.5 * normal              # radar returns 1.5 m off the ray, near face
    obs = observe(_frame([pts], cam), m)
    radar = observe(_frame([pts], cam), ObservationModel(camera_bearing=False))
    off = (obs.centres[0] - origin) @ normal
    assert 0.0 < off < 0.5 * 1.5                          # pulled most of the way onto the camera's ray
    along_shift = (obs.centres[0] - radar.centres[0]) @ ray
    assert abs(along_shift) < 0.05                        # the range stays the radar's
    w, v = np.linalg.eigh(obs.cov[0])
    assert np.sqrt(w[0]) < m.camera_across_m + m.camera_across_rad * 41 and abs(v[:, 0] @ normal) > 0.99
    assert np.sqrt(w[1]) == pytest.approx(m.along_points_m)


def test_the_camera_estimate_rescues_a_vehicle_with_wrong_points():
    truth = np.array([0.0, 40.0])
    A = observe(_frame([truth + [0, 12.0]], truth[None]))      # points of the car 12 m behind it
    B = observe(_frame([truth - [0, 1.4]], truth[None] + [0, 1.0]))
    d, mode = mahalanobis(A, B, np.eye(2)[None], np.zeros((1, 2)), with_modes=True)
    assert d[0, 0, 0] < 2.5 and mode[0, 0, 0] == 2          # own camera estimate, other's points (pair gate 2.5)
    off = observe(_frame([truth + [6.0, 12.0]], truth[None] + [10.0, 0.0]))   # both off across the ray
    assert mahalanobis(off, B, np.eye(2)[None], np.zeros((1, 2)))[0, 0, 0] > 3.0


def test_refinement_pulls_a_rough_start_onto_vehicles_background_and_heading():
    rng = np.random.default_rng(3)
    T_R, T_t = _rot(30), np.array([5.0, 25.0])
    cars = rng.uniform([-20, 15], [20, 60], (5, 2))
    wall = np.column_stack([np.full(120, -12.0), np.linspace(0, 80, 120)])
    wall2 = np.column_stack([np.linspace(-12, 20, 60), np.full(60, 70.0)])
    bg = np.vstack([wall, wall2])
    to_cav = lambda p: (p - T_t) @ T_R           # noqa: E731  (R^T (p - t), row-wise)
    own = _frame(list(cars), cars, np.c_[bg, np.zeros(len(bg))])
    oth_cars = to_cav(cars) + rng.normal(0, 0.3, cars.shape)
    other = _frame(list(oth_cars), oth_cars, np.c_[to_cav(bg), np.zeros(len(bg))])
    A, B = observe(own), observe(other)
    D = np.zeros((5, 5))
    R, t = refine(A, B, D, own.background[:, :2], other.background[:, :2], _rot(34), T_t + [2.0, -1.5],
                  yaws=np.radians([30.0, 120.0, 210.0, 300.0]))
    assert abs(np.degrees(np.arctan2(R[1, 0], R[0, 0])) - 30) < 0.5
    assert np.linalg.norm(t - T_t) < 0.6


def test_refining_many_hypotheses_at_once_gives_each_its_own_fit():
    from mmatch.ego.refine import refine_many
    rng = np.random.default_rng(5)
    T_R, T_t = _rot(30), np.array([5.0, 25.0])
    cars = rng.uniform([-20, 15], [20, 60], (6, 2))
    bg = np.vstack([np.column_stack([np.full(90, -12.0), np.linspace(0, 80, 90)]),
                    np.column_stack([np.linspace(-12, 20, 40), np.full(40, 70.0)])])
    to_cav = lambda p: (p - T_t) @ T_R           # noqa: E731
    own = _frame(list(cars), cars, np.c_[bg, np.zeros(len(bg))])
    oth = to_cav(cars) + rng.normal(0, 0.3, cars.shape)
    other = _frame(list(oth), oth, np.c_[to_cav(bg) + rng.normal(0, 0.2, bg.shape), np.zeros(len(bg))])
    A, B, D = observe(own), observe(other), np.zeros((6, 6))
    yaws = np.radians([30.0, 120.0, 210.0, 300.0])
    R0 = np.stack([_rot(d) for d in (34.0, 25.0, 30.0, 120.0, -60.0)])
    t0 = T_t + rng.normal(0, 2.0, (5, 2))
    t0[0] = T_t + [1.0, -1.0]
    args = (A, B, D, own.background[:, :2], other.background[:, :2])
    Rs, ts = refine_many(*args, R0, t0, yaws)
    for h in range(len(R0)):
        R1, t1 = refine(*args, R0[h], t0[h], yaws)
        np.testing.assert_allclose(Rs[h], R1, atol=1e-9)
        np.testing.assert_allclose(ts[h], t1, atol=1e-9)
    assert np.linalg.norm(ts[0] - T_t) < 0.6                      # and the near start converges


def test_the_refinement_solves_its_normal_equations_exactly_and_skips_singular_ones():
    from mmatch.ego.refine import _solve3
    rng = np.random.default_rng(0)
    J = rng.normal(size=(20, 5, 3))
    M = J.transpose(0, 2, 1) @ J                                  # symmetric positive definite
    M[3] = 0.0                                                     # nothing to solve
    M[7, 1, :] = M[7, :, 1] = 0.0                                  # no x information
    b = rng.normal(size=(20, 3))
    x, ok = _solve3(M, b)
    assert not ok[3] and not ok[7] and ok.sum() == 18
    np.testing.assert_array_equal(x[~ok], 0.0)
    np.testing.assert_allclose(x[ok], np.linalg.solve(M[ok], b[ok][..., None])[..., 0], rtol=1e-9, atol=1e-12)


def test_constrained_aligner_beats_anchored_icp_with_true_pairs(hard_dir):
    """Oracle pairs on label frames: the one least-squares fit aligns more scenes than ICP."""
    oracle, consensus = get_matcher("oracle"), get_matcher("consensus")
    ok = {"constrained": 0, "anchored-icp": 0}
    tp = pred = gt = 0
    files = sorted(hard_dir.glob("*.npz"))
    for f in files:
        s = load_scene(f)
        own, other = shared_from_labels(s.ego, "ego"), shared_from_labels(s.cav, "cav")
        o = oracle(own, other, MatchContext(s.gt_pairs))
        for name in ok:
            res = get_aligner(name)(own, other, o)
            ok[name] += res.T is not None and rre_deg(s.gt_T_ego_cav, res.T) < 5 and rte_m(s.gt_T_ego_cav, res.T) < 2
        m = consensus(own, other, MatchContext())
        boxes = np.column_stack([own.vehicle_box_index[m.pairs[:, 0]], other.vehicle_box_index[m.pairs[:, 1]]])
        a, b, c = pair_counts(boxes, s.gt_pairs)
        tp, pred, gt = tp + a, pred + b, gt + c
    print(f"\n{len(files)} hard label scenes, oracle pairs: success {ok}; consensus P {tp / pred:.2f} R {tp / gt:.2f}")
    assert ok["constrained"] >= ok["anchored-icp"] and ok["constrained"] / len(files) > 0.5
    assert tp / pred > 0.7 and tp / gt > 0.7


def test_a_detector_with_lower_scores_overall_still_gets_its_pairs(hard_dir):
    import dataclasses

    consensus = get_matcher("consensus")
    found = {1.0: 0, 0.45: 0}
    for f in sorted(hard_dir.glob("*.npz"))[:12]:
        s = load_scene(f)
        for scale in found:
            views = []
            for v, name in ((s.ego, "ego"), (s.cav, "cav")):
                fr = shared_from_labels(v, name)
                boxes = fr.vehicle_boxes.copy()
                boxes[:, 4] *= scale
                views.append(dataclasses.replace(fr, vehicle_boxes=boxes))
            m = consensus(views[0], views[1], MatchContext())
            pairs = np.column_stack([views[0].vehicle_box_index[m.pairs[:, 0]],
                                     views[1].vehicle_box_index[m.pairs[:, 1]]])
            found[scale] += pair_counts(pairs, s.gt_pairs)[0]
    assert found[0.45] >= 0.8 * found[1.0] > 0


def test_one_fusion_observes_each_frame_once_and_the_shared_arrays_cannot_be_changed():
    from dataclasses import replace

    from mmatch.ego.observations import observations_shared

    f = _frame([[0.0, 30.0], None], np.array([[0.0, 31.0], [30.0, 0.0]]))
    assert observe(f) is not observe(f)                             # outside: computed each time
    with observations_shared():
        a = observe(f)
        assert observe(f) is a and observe(f, ObservationModel(camera_bearing=False)) is not a
        b = observe(f, ObservationModel(camera_penalty=2.0))      # the confidence model's penalty
        assert b.centres is a.centres and b.cov is a.cov            # same geometry, computed once
        assert b.cam_penalty[0] == 2.0 and a.cam_penalty[0] == ObservationModel().camera_penalty
        assert observe(replace(f)) is not a                          # another frame object
        with pytest.raises(ValueError):
            a.centres[0, 0] = 1.0
    assert observe(f) is not a


def _random_observations(rng: np.random.Generator, V: int):
    from mmatch.ego.observations import Observations
    c = rng.uniform(-40, 40, (V, 2))
    S = np.eye(2)[None] * rng.uniform(0.3, 3.0, (V, 1, 1))
    return Observations(c, S, c + rng.normal(0, 1.0, (V, 2)), 2 * S, np.where(rng.random(V) < 0.5, 2.0, 0.0))


@pytest.mark.parametrize("V", [1, 3, 12])
def test_mahalanobis_takes_the_best_of_the_four_estimate_combinations(V):
    rng = np.random.default_rng(V)
    A, B = _random_observations(rng, V), _random_observations(rng, V + 2)
    R, t = np.stack([_rot(d) for d in rng.uniform(-180, 180, 6)]), rng.uniform(-20, 20, (6, 2))
    d, mode = mahalanobis(A, B, R, t, with_modes=True)
    ref = np.full(d.shape + (4,), np.inf)
    for ma, (ca, Sa, pa) in enumerate(A.modes()):
        for mb, (cb, Sb, pb) in enumerate(B.modes()):
            for h in range(len(R)):
                for i in range(len(ca)):
                    for j in range(len(cb)):
                        S = Sa[i] + R[h] @ Sb[j] @ R[h].T
                        r = ca[i] - (R[h] @ cb[j] + t[h])
                        ref[h, i, j, 2 * ma + mb] = r @ np.linalg.solve(S, r) + pa[i] + pb[j]
    np.testing.assert_allclose(d, np.sqrt(ref.min(axis=3)), rtol=1e-4, atol=1e-4)
    best = np.take_along_axis(ref, mode[..., None].astype(int), axis=3)[..., 0]
    np.testing.assert_allclose(best, ref.min(axis=3), rtol=1e-4, atol=1e-3)   # the mode is a best one



@pytest.mark.parametrize("V", [1, 3, 12])
def test_modes_at_a_few_pairs_are_the_modes_of_the_full_table(V):
    from mmatch.ego.observations import best_combination, combination_squares, modes_at, paired
    rng = np.random.default_rng(V)
    A, B = _random_observations(rng, V), _random_observations(rng, V + 2)
    R, t = np.stack([_rot(d) for d in rng.uniform(-180, 180, 6)]), rng.uniform(-20, 20, (6, 2))
    q = combination_squares(paired(A, B), R, t)
    _, mode = best_combination(q, V, V + 2, with_modes=True)                 # (Va, Vb, H)
    a, b, h = np.nonzero(np.ones(mode.shape, bool))
    np.testing.assert_array_equal(modes_at(q, V, V + 2, a, b, h), mode[a, b, h])

def _boxed(points: list, box_px: tuple[float, float]) -> SharedFrame:
    """One vehicle with radar points `points` (x, y) and a camera box of (width, height) px."""
    f = _frame([None], np.array([[0.0, 30.0]]))
    f.vehicle_points = np.array([[x, y, 0.0, 0.0, 10.0] for x, y in points], np.float32)
    f.vehicle_index = np.zeros(len(points), np.int32)
    f.vehicle_boxes = np.array([[100, 100, 100 + box_px[0], 100 + box_px[1], 0.9, 30]], np.float32)
    return f


def test_the_far_side_shift_grows_with_a_tall_narrow_box_and_shrinks_with_deep_returns():
    end_on = FAR_SIDE.shifts(_boxed([[0.0, 30.0]], (40, 60)))[0]      # taller than wide: seen end-on
    side_on = FAR_SIDE.shifts(_boxed([[0.0, 30.0]], (120, 40)))[0]    # wide and low: side-on
    assert end_on == pytest.approx(FAR_SIDE.base_m + FAR_SIDE.per_aspect * 1.5)
    assert side_on == pytest.approx(FAR_SIDE.base_m + FAR_SIDE.per_aspect / 3)
    assert end_on > side_on + 1.0
    # the returns reach 3 m beyond the nearest already: the centroid needs less of a push
    deep = FAR_SIDE.shifts(_boxed([[0.0, 30.0], [0.0, 33.0]], (40, 60)))[0]
    assert deep == pytest.approx(end_on + FAR_SIDE.per_beyond_near * 1.5) and deep < end_on
    # clipped; a vehicle without points keeps its camera centre
    assert FAR_SIDE.shifts(_boxed([[0.0, 30.0]], (10, 400)))[0] == FAR_SIDE.max_m
    flat = FarSideModel(per_aspect=0.0, per_beyond_near=0.0, base_m=1.0)
    c = far_side_centres(_boxed([[0.0, 30.0]], (40, 60)), flat)
    np.testing.assert_allclose(c, [[0.0, 31.0]])
    none = _frame([None], np.array([[3.0, 30.0]]))
    np.testing.assert_allclose(far_side_centres(none), [[3.0, 30.0]])
