"""process_view end to end on synthetic frames: what is shared, how precise, how big; bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mmatch.cav.config import BackgroundConfig, CavConfig
from mmatch.cav.plausibility import duplicates
from mmatch.cav.process import REPAIRS, STAGES, CavInputError, ViewProcessor, process_view, run_view
from mmatch.codec import decode, encode
from mmatch.shared import MOVING_SKETCH_MAX

from .synth import STATIONARY, make_frame


def run(f, config=None):
    return process_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 12.5,
                        sender="cav-1", seq=3, config=config)


def test_shared_frame_structure():
    f = make_frame(1, n_moving=6)
    frame, ms = run(f)
    assert set(ms) == set(STAGES) and all(v >= 0 for v in ms.values())
    assert frame.sender == "cav-1" and frame.seq == 3 and frame.stamp == 12.5
    V = frame.num_vehicles
    # every box but second detections of one vehicle and false detections the radar does not
    # back (the synthetic frame's last box, low score, no returns)
    kept = frame.vehicle_box_index
    real = np.flatnonzero((f.box_ids >= 0) & ~duplicates(f.boxes))
    assert set(real) <= set(kept.tolist()) and len(f.boxes) - 1 not in kept
    assert np.all(np.diff(kept) > 0) and V == len(kept)
    np.testing.assert_array_equal(frame.vehicle_features, f.features[kept])
    assert frame.vehicle_centers.shape == (V, 2) and frame.vehicle_points.shape[1] == 5
    assert np.all(np.diff(frame.vehicle_index) >= 0)      # grouped by vehicle
    assert frame.vehicle_index.max() < V
    assert frame.background.shape[1] == 3 and len(frame.background) > 20
    np.testing.assert_allclose(frame.ego_velocity, f.velocity, atol=0.2)


def test_moving_point_precision_and_recall_on_synthetic_frames():
    tp = fp = fn = fn_boxed = right_vehicle = 0
    for seed in range(40):
        f = make_frame(seed, n_moving=2 + seed % 9, perpendicular=seed % 3 == 0)
        out = run_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 0.0)
        pv = out.point_vehicle
        np.testing.assert_array_equal(f.points[pv >= 0][np.argsort(pv[pv >= 0], kind="stable")],
                                      out.frame.vehicle_points)          # diagnostics agree with the frame
        called = (pv >= 0) & np.append(out.vehicle_moving, False)[pv]
        gt = f.gt_moving
        tp += np.sum(called & gt)
        fp += np.sum(called & ~gt)
        fn += np.sum(~called & gt)
        fn_boxed += np.sum(~called & gt & np.isin(f.labels, f.box_ids))
        box_vehicle = np.append(f.box_ids[out.frame.vehicle_box_index], -9)[pv]
        right_vehicle += np.sum(called & (box_vehicle == f.labels))
    precision, recall = tp / (tp + fp), tp / (tp + fn)
    print(f"\nmoving-vehicle points on 40 synthetic frames: precision {precision:.3f}, recall {recall:.3f}, "
          f"recall of detected vehicles {tp / (tp + fn_boxed):.3f}, in the right vehicle {right_vehicle / (tp + fp):.3f}")
    assert precision >= 0.9
    assert recall >= 0.85
    assert right_vehicle / (tp + fp) >= 0.8


def test_parked_cars_are_vehicles_with_their_stationary_points():
    right = shared = n_boxes = n_moving = 0
    centre_err = []
    for seed in range(12):
        f = make_frame(seed, n_moving=0, n_parked=3, perpendicular=False, ghosts=False, clutter=0)
        out = run_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 0.0)
        frame, pv = out.frame, out.point_vehicle
        assert set(np.flatnonzero(f.box_ids >= 0)) <= set(frame.vehicle_box_index.tolist())   # every parked car
        n_boxes += len(f.boxes)
        n_moving += out.vehicle_moving.sum()             # nothing moves in these frames
        box_vehicle = np.append(f.box_ids[frame.vehicle_box_index], -9)[pv]
        right += np.sum((pv >= 0) & (box_vehicle == f.labels))
        shared += np.sum(pv >= 0)
        for v, b in enumerate(frame.vehicle_box_index):   # centres near the cars
            k = f.box_ids[b]
            if k >= 0 and np.sum(frame.vehicle_index == v) >= 2:
                centre_err.append(np.linalg.norm(frame.points_of(v)[:, :2].mean(0) - f.centres[k]))
        # shared points leave the background sketch
        if len(frame.background) and np.any(pv >= 0):
            d = np.min(np.linalg.norm(frame.background[None, :, :2] - frame.vehicle_points[:, None, :2], axis=2), axis=1)
            assert np.mean(d < 0.01) < 0.5
    print(f"\nparked cars, 12 synthetic frames: {shared} points shared, {right / shared:.3f} on the box's car "
          f"(the rest: guardrail and facade returns at the same bearing and depth); "
          f"{n_moving} of {n_boxes} boxes wrongly judged moving; point-centroid to car centre median "
          f"{np.median(centre_err):.2f} m")
    assert shared >= 60 and right / shared >= 0.6
    assert n_moving <= 0.1 * n_boxes
    assert np.median(centre_err) < 2.5                    # near-face centroid: ~1-2 m short of the centre


def test_a_lone_ghost_does_not_make_a_parked_car_move():
    f = make_frame(5, n_moving=0, n_parked=3, perpendicular=False, ghosts=False, clutter=0)
    before = run_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 0.0)
    counts = np.bincount(before.frame.vehicle_index, minlength=before.frame.num_vehicles)
    v = int(np.argmax(counts))
    assert counts[v] >= 3 and not before.vehicle_moving[v]
    ghost = before.frame.vehicle_points[before.frame.vehicle_index == v][:1].copy()
    ghost[0, 3] += 9.0                                     # same place, moving Doppler
    pts = np.vstack([f.points, ghost])
    out = run_view(pts, f.boxes, f.features, f.camera, f.radar_height, 0.0)
    assert not out.vehicle_moving[v]
    assert out.point_vehicle[-1] == -1                     # the ghost is not shared


def test_background_drops_isolated_points_and_respects_the_cap():
    f = make_frame(2)
    frame, _ = run(f)
    stationary = f.points[f.labels == STATIONARY]
    assert len(frame.background) <= len(stationary)
    lone = np.array([[30.0, 95.0, 0.0, 0.0, 10.0]], np.float32)       # one far, isolated point
    pts = np.vstack([f.points, lone])
    pts[-1, 3] = -float(f.velocity[1]) * 95 / np.hypot(30, 95)         # stationary-looking
    frame2, _ = process_view(pts, f.boxes, f.features, f.camera, 0.8, 0.0)
    assert np.min(np.linalg.norm(frame2.background[:, :2] - [30, 95], axis=1)) > 3
    small, _ = run(f, CavConfig(background=BackgroundConfig(max_points=10)))
    assert len(small.background) == 10


def test_encoded_frame_is_small():
    sizes = []
    for seed in range(10):
        frame, _ = run(make_frame(seed, n_moving=9))
        data = encode(frame)
        assert decode(data).num_vehicles == frame.num_vehicles
        sizes.append(len(data))
    print(f"\nencoded shared frame: median {np.median(sizes):.0f} B, max {max(sizes)} B")
    assert max(sizes) <= 9 * 1024


def test_empty_and_degenerate_frames_never_raise():
    f = make_frame(0)
    frame, ms = process_view(np.zeros((0, 5), np.float32), f.boxes, f.features, f.camera, 0.8, 1.0)
    assert frame.num_vehicles == int((~duplicates(f.boxes)).sum()) and len(frame.vehicle_points) == 0
    assert np.all(np.isnan(frame.ego_velocity)) and set(ms) == set(STAGES)
    assert np.all(np.isfinite(frame.vehicle_centers))      # from box bearing and depth
    frame, _ = process_view(f.points, np.zeros((0, 6), np.float32), np.zeros((0, 32), np.float32),
                            f.camera, 0.8, 1.0)
    assert frame.num_vehicles == 0 and len(frame.vehicle_points) == 0 and len(frame.background) > 0
    frame, _ = process_view(np.zeros((0, 5)), np.zeros((0, 6)), np.zeros((0, 32)), f.camera, 0.8, 1.0)
    assert frame.num_vehicles == 0 and len(frame.background) == 0
    decode(encode(frame))
    pts = f.points.copy()
    pts[::7, 0] = np.nan
    frame, _ = process_view(pts, f.boxes, f.features, f.camera, 0.8, 1.0)
    assert np.all(np.isfinite(frame.vehicle_points)) and np.all(np.isfinite(frame.background))
    bad_boxes = f.boxes.copy()
    bad_boxes[0, 0] = np.nan
    frame, _ = process_view(f.points, bad_boxes, f.features, f.camera, 0.8, 1.0)
    assert 0 not in frame.vehicle_box_index.tolist()


def test_descriptors_are_shared_as_distributions_whatever_their_scale():
    """A sender counting pixels instead of normalising, or leaving a group empty: the shared
    descriptors are distributions per H, S, V group (the wire carries 0-1 a bin), so the
    receiver reads the same appearance as from a normalised sender."""
    f = make_frame(2, n_moving=4)
    ref, _ = run(f)
    counts = f.features * 500.0
    counts[0, 16:24] = 0.0                                  # saturation not measured
    counts[1, 3] = -2.0                                     # a negative bin
    frame, _ = process_view(f.points, f.boxes, counts, f.camera, f.radar_height, 12.5)
    np.testing.assert_array_equal(frame.vehicle_box_index, ref.vehicle_box_index)
    got = {int(b): frame.vehicle_features[k] for k, b in enumerate(frame.vehicle_box_index)}
    for k, b in enumerate(ref.vehicle_box_index):
        want = ref.vehicle_features[k].copy()
        if b == 0:
            want[16:24] = 1 / 8
        if b == 1:
            want[:16] = np.clip(f.features[1, :16], 0, None)
            want[3] = 0.0
            want[:16] /= want[:16].sum()
        np.testing.assert_allclose(got[int(b)], want, atol=1e-6)
    for lo, hi in ((0, 16), (16, 24), (24, 32)):
        np.testing.assert_allclose(frame.vehicle_features[:, lo:hi].sum(axis=1), 1.0, atol=1e-5)
    back = decode(encode(frame)).vehicle_features
    np.testing.assert_allclose(back, frame.vehicle_features, atol=1 / 255)


def test_a_dense_frame_is_thinned_to_the_same_points_whatever_their_order():
    """A radar far denser than the models were fit on: at most inputs.max_points of its usable
    returns go on, chosen by their values, so the shared frame does not depend on the order."""
    f = make_frame(5, n_moving=5)
    rng = np.random.default_rng(1)
    pts = np.vstack([f.points] + [f.points + rng.normal(0, [0.05, 0.05, 0.02, 0.05, 0.5], f.points.shape)
                                  for _ in range(7)]).astype(np.float32)
    cfg = CavConfig(inputs=replace(CavConfig().inputs, max_points=300))
    a, _ = process_view(pts, f.boxes, f.features, f.camera, f.radar_height, 1.0, config=cfg)
    perm = rng.permutation(len(pts))
    b, _ = process_view(pts[perm], f.boxes, f.features, f.camera, f.radar_height, 1.0, config=cfg)
    np.testing.assert_array_equal(a.vehicle_box_index, b.vehicle_box_index)
    np.testing.assert_array_equal(np.unique(a.vehicle_points, axis=0), np.unique(b.vehicle_points, axis=0))
    np.testing.assert_array_equal(np.unique(a.background, axis=0), np.unique(b.background, axis=0))
    out = run_view(pts, f.boxes, f.features, f.camera, f.radar_height, 1.0, config=cfg)
    assert len(out.frame.vehicle_points) <= 300 < len(pts)
    uncapped = CavConfig(inputs=replace(CavConfig().inputs, max_points=0))
    full, _ = process_view(pts, f.boxes, f.features, f.camera, f.radar_height, 1.0, config=uncapped)
    assert len(full.vehicle_points) > len(a.vehicle_points)
    ref, _ = process_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 1.0)
    capped, _ = process_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 1.0, config=cfg)
    np.testing.assert_array_equal(ref.vehicle_points, capped.vehicle_points)     # within the cap: as it is


def test_a_box_without_a_depth_is_placed_by_the_size_prior():
    """A detector without a depth output (0), or none for one box (NaN, negative): the box is
    still a vehicle, at the distance where a 1.5 m tall vehicle fills its pixel height; with
    inputs.unknown_depth_height_m = 0 such boxes are no vehicles (the behaviour before)."""
    f = make_frame(3, n_moving=5)
    ref, _ = run(f)
    boxes = f.boxes.copy()
    boxes[:, 5] = 0.0
    boxes[1, 5], boxes[2, 5] = np.nan, -4.0
    frame, _ = process_view(f.points, boxes, f.features, f.camera, f.radar_height, 12.5)
    real = np.flatnonzero(f.box_ids >= 0)
    shared = np.intersect1d(frame.vehicle_box_index, real)
    assert len(shared) >= len(np.intersect1d(ref.vehicle_box_index, real)) - 1 and {1, 2} <= set(shared.tolist())
    at = {int(b): k for k, b in enumerate(frame.vehicle_box_index)}
    placed = np.array([frame.vehicle_boxes[at[b], 5] for b in shared])
    assert np.all(np.abs(placed / f.boxes[shared, 5] - 1) < 0.4)          # the detector's: 12 % off
    ranges = np.linalg.norm(frame.vehicle_centers[[at[b] for b in shared]], axis=1)
    assert np.all(np.abs(ranges / f.boxes[shared, 5] - 1) < 0.4)
    decode(encode(frame))
    off = CavConfig(inputs=replace(CavConfig().inputs, unknown_depth_height_m=0.0))
    frame, _ = process_view(f.points, boxes, f.features, f.camera, f.radar_height, 12.5, config=off)
    assert frame.num_vehicles == 0


def test_moving_returns_no_vehicle_holds_are_shared_as_the_moving_sketch():
    """The moving returns the frame shares beside its vehicles: those the ego-motion fit calls
    moving that no shared vehicle owns; at most MOVING_SKETCH_MAX, the same whatever the order."""
    f = make_frame(6, n_moving=5)
    out = run_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 1.0)
    moving = out.ego.moving
    owned = out.point_vehicle[out.rows] >= 0
    want = f.points[out.rows][moving & ~owned, :2]
    np.testing.assert_array_equal(np.unique(out.frame.moving, axis=0), np.unique(want, axis=0))
    assert len(out.frame.moving) > 0
    rng = np.random.default_rng(2)
    extra = np.column_stack([rng.uniform(-30, 30, 200), rng.uniform(10, 80, 200), np.zeros(200),
                             rng.uniform(5, 9, 200), np.full(200, 20.0)]).astype(np.float32)
    pts = np.vstack([f.points, extra])
    a = run_view(pts, f.boxes, f.features, f.camera, f.radar_height, 1.0).frame.moving
    perm = rng.permutation(len(pts))
    b = run_view(pts[perm], f.boxes, f.features, f.camera, f.radar_height, 1.0).frame.moving
    assert len(a) == MOVING_SKETCH_MAX
    np.testing.assert_array_equal(np.unique(a, axis=0), np.unique(b, axis=0))
    np.testing.assert_allclose(decode(encode(out.frame)).moving, out.frame.moving, atol=0.005)


def test_what_the_inputs_needed_is_counted_per_frame_and_over_a_run(caplog):
    """Each repair the CAV side makes to its inputs is counted: returns dropped (non-finite,
    implausible) or thinned, depths placed by the size prior, descriptors rescaled; a frame
    that needed none counts none; a run adds them up and warns once per kind."""
    f = make_frame(4, n_moving=5)
    clean = run_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 1.0)
    assert clean.repairs == {k: 0 for k in REPAIRS}
    pts = f.points.copy()
    pts[0, 3], pts[1, 0], pts[2, 4] = np.nan, 5000.0, np.inf
    boxes, feats = f.boxes.copy(), f.features.copy()
    boxes[0, 5], boxes[1, 5] = 0.0, np.nan
    feats[2] *= 300.0
    cfg = CavConfig(inputs=replace(CavConfig().inputs, max_points=len(pts) - 13))
    out = run_view(pts, boxes, feats, f.camera, f.radar_height, 1.0, config=cfg)
    assert out.repairs == {"points_dropped": 3, "points_thinned": 10, "depths_by_size_prior": 2,
                           "descriptors_rescaled": 1}
    proc = ViewProcessor(cfg)
    with caplog.at_level("WARNING", logger="mmatch.cav.process"):
        for k in range(3):
            proc(pts, boxes, feats, f.camera, f.radar_height, 0.05 * k, sender="cav1", seq=k)
            proc(f.points, f.boxes, f.features, f.camera, f.radar_height, 0.05 * k + 0.025, sender="cav1", seq=k)
    want = {k: 3 * v for k, v in out.repairs.items()}
    want["points_thinned"] += 3 * 13                        # the clean frames exceed the cap too
    assert dict(proc.repairs) == want
    warned = [r.getMessage() for r in caplog.records if r.getMessage().startswith("inputs:")]
    assert len(warned) == 4 and all("cav1/0" in m for m in warned)


@pytest.mark.parametrize("points, boxes, features", [
    (np.zeros((5, 4)), np.zeros((0, 6)), np.zeros((0, 32))),
    (np.zeros((5, 5)), np.zeros((2, 5)), np.zeros((2, 32))),
    (np.zeros((5, 5)), np.zeros((2, 6)), np.zeros((3, 32))),
])
def test_wrong_shapes_raise_cav_input_error(points, boxes, features):
    f = make_frame(0)
    with pytest.raises(CavInputError):
        process_view(points, boxes, features, f.camera, 0.8, 1.0)


def test_a_box_the_canonical_image_cannot_carry_is_not_shared():
    """Boxes go on the wire in the canonical image (focal 1000 px): a camera of short focal
    length makes a corner within max_pixel of its own image too far out there, which the
    encoder would refuse. Such a box is no vehicle; the frame stays encodable."""
    f = make_frame(4, n_moving=3)
    K = f.camera.K.copy()
    K[0, 0] = K[1, 1] = 400.0
    cam = replace(f.camera, K=K)
    boxes = f.boxes.copy()
    boxes[0, 2] = 15000.0                                  # 1000 x (15000 - cx) / 400 > 16383 canonical px
    frame, _ = process_view(f.points, boxes, f.features, cam, f.radar_height, 0.0)
    assert 0 not in frame.vehicle_box_index.tolist()
    assert np.abs(frame.vehicle_boxes[:, :4]).max() <= 16000
    decode(encode(frame))


def test_without_an_ego_motion_estimate_boxes_keep_their_points():
    f = make_frame(4, n_moving=3, n_parked=0, clutter=0, ghosts=False)
    k = next(int(i) for i in f.box_ids if i >= 0 and np.sum(f.labels == i) >= 3)
    pts = f.points[f.labels == k]                          # only one vehicle's points: no background
    frame, _ = process_view(pts, f.boxes, f.features, f.camera, 0.8, 1.0)
    assert np.all(np.isnan(frame.ego_velocity))
    v = int(np.flatnonzero(f.box_ids[frame.vehicle_box_index] == k)[0])
    assert np.sum(frame.vehicle_index == v) >= 0.5 * len(pts)


_floats = st.floats(allow_nan=True, allow_infinity=True, width=32)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10**6), n=st.integers(0, 60), m=st.integers(0, 6), junk=st.lists(_floats, min_size=8, max_size=8),
       scale=st.sampled_from([1.0, 50.0, 1e4]))
def test_any_input_of_the_right_shape_gives_an_encodable_frame(seed, n, m, junk, scale):
    rng = np.random.default_rng(seed)
    f = make_frame(seed % 50)
    pts = (rng.normal(0, scale, (n, 5))).astype(np.float32)
    boxes = np.column_stack([rng.uniform(-100, 1400, (m, 4)) * scale / 50, rng.uniform(-0.5, 1.5, m),
                             rng.uniform(-10, 400, m)]).astype(np.float32)
    feats = rng.uniform(-0.2, 1.2, (m, 32)).astype(np.float32)
    flat = np.concatenate([pts.ravel(), boxes.ravel(), feats.ravel()])
    if flat.size:                                   # sprinkle NaN / inf / extremes at random places
        where = rng.integers(0, flat.size, len(junk))
        flat[where] = np.asarray(junk, np.float32)
        pts = flat[:pts.size].reshape(pts.shape)
        boxes = flat[pts.size:pts.size + boxes.size].reshape(boxes.shape)
        feats = flat[pts.size + boxes.size:].reshape(feats.shape)
    frame, ms = process_view(pts, boxes, feats, f.camera, 0.8, 1.0)
    assert set(ms) == set(STAGES)
    back = decode(encode(frame))
    assert back.num_vehicles == frame.num_vehicles and len(back.vehicle_points) == len(frame.vehicle_points)
