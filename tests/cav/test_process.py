"""process_view end to end on synthetic frames: what is shared, how precise, how big; bad input."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.cav.config import BackgroundConfig, CavConfig
from mmatch.cav.process import STAGES, CavInputError, process_view
from mmatch.codec import decode, encode

from .synth import STATIONARY, make_frame


def shared_mask(frame_points: np.ndarray, shared_points: np.ndarray) -> np.ndarray:
    """Which input rows were shared as vehicle points (exact float32 row match)."""
    index = {row: i for i, row in enumerate(map(tuple, frame_points.tolist()))}
    mask = np.zeros(len(frame_points), bool)
    for row in map(tuple, shared_points.tolist()):
        mask[index[row]] = True
    return mask


def run(f, config=None):
    return process_view(f.points, f.boxes, f.features, f.camera, f.radar_height, 12.5,
                        sender="cav-1", seq=3, config=config)


def test_shared_frame_structure():
    f = make_frame(1, n_moving=6)
    frame, ms = run(f)
    assert set(ms) == set(STAGES) and all(v >= 0 for v in ms.values())
    assert frame.sender == "cav-1" and frame.seq == 3 and frame.stamp == 12.5
    V = frame.num_vehicles
    assert V == len(f.boxes)                               # every box is a vehicle (min score 0)
    np.testing.assert_array_equal(frame.vehicle_box_index, np.arange(V))
    np.testing.assert_array_equal(frame.vehicle_features, f.features)
    assert frame.vehicle_centers.shape == (V, 2) and frame.vehicle_points.shape[1] == 5
    assert np.all(np.diff(frame.vehicle_index) >= 0)      # grouped by vehicle
    assert frame.vehicle_index.max() < V
    assert frame.background.shape[1] == 3 and len(frame.background) > 20
    np.testing.assert_allclose(frame.ego_velocity, f.velocity, atol=0.2)


def test_moving_point_precision_and_recall_on_synthetic_frames():
    tp = fp = fn = fn_boxed = right_vehicle = 0
    for seed in range(40):
        f = make_frame(seed, n_moving=2 + seed % 9, perpendicular=seed % 3 == 0)
        frame, _ = run(f)
        sent = shared_mask(f.points, frame.vehicle_points)
        gt = f.gt_moving
        tp += np.sum(sent & gt)
        fp += np.sum(sent & ~gt)
        fn += np.sum(~sent & gt)
        fn_boxed += np.sum(~sent & gt & np.isin(f.labels, f.box_ids))
        # each shared point sits in the vehicle its box shows
        box_vehicle = f.box_ids[frame.vehicle_box_index][frame.vehicle_index]
        truth = f.labels[[np.flatnonzero(np.all(f.points == p, axis=1))[0] for p in frame.vehicle_points]]
        right_vehicle += np.sum(box_vehicle == truth)
    precision, recall = tp / (tp + fp), tp / (tp + fn)
    print(f"\nshared vehicle points on 40 synthetic frames: precision {precision:.3f}, recall {recall:.3f}, "
          f"recall of detected vehicles {tp / (tp + fn_boxed):.3f}, in the right vehicle {right_vehicle / (tp + fp):.3f}")
    assert precision >= 0.9
    assert recall >= 0.85
    assert right_vehicle / (tp + fp) >= 0.8


def test_parked_car_goes_to_the_background():
    f = make_frame(5, n_moving=0, n_parked=3, perpendicular=False, ghosts=False, clutter=0)
    frame, _ = run(f)
    assert len(frame.vehicle_points) == 0                  # nothing moves
    assert frame.num_vehicles == len(f.boxes)              # boxes still shared with descriptors
    parked_pts = f.points[f.labels >= 0, :2]
    d = np.min(np.linalg.norm(frame.background[:, None, :2] - parked_pts[None], axis=2), axis=0)
    assert np.mean(d < 0.6) > 0.5                          # the sketch covers the parked cars
    for v, b in enumerate(frame.vehicle_box_index):       # centres from their stationary points
        k = f.box_ids[b]
        if k >= 0:
            assert np.linalg.norm(frame.vehicle_centers[v] - f.centres[k]) < 3.5


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
    assert frame.num_vehicles == len(f.boxes) and len(frame.vehicle_points) == 0
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
    bad_boxes[0, 5] = np.nan
    frame, _ = process_view(f.points, bad_boxes, f.features, f.camera, 0.8, 1.0)
    assert 0 not in frame.vehicle_box_index.tolist()


@pytest.mark.parametrize("points, boxes, features", [
    (np.zeros((5, 4)), np.zeros((0, 6)), np.zeros((0, 32))),
    (np.zeros((5, 5)), np.zeros((2, 5)), np.zeros((2, 32))),
    (np.zeros((5, 5)), np.zeros((2, 6)), np.zeros((3, 32))),
])
def test_wrong_shapes_raise_cav_input_error(points, boxes, features):
    f = make_frame(0)
    with pytest.raises(CavInputError):
        process_view(points, boxes, features, f.camera, 0.8, 1.0)


def test_without_an_ego_motion_estimate_boxes_keep_their_points():
    f = make_frame(4, n_moving=3, n_parked=0, clutter=0, ghosts=False)
    k = next(int(i) for i in f.box_ids if i >= 0 and np.sum(f.labels == i) >= 3)
    pts = f.points[f.labels == k]                          # only one vehicle's points: no background
    frame, _ = process_view(pts, f.boxes, f.features, f.camera, 0.8, 1.0)
    assert np.all(np.isnan(frame.ego_velocity))
    v = int(np.flatnonzero(f.box_ids[frame.vehicle_box_index] == k)[0])
    assert np.sum(frame.vehicle_index == v) >= 0.5 * len(pts)
