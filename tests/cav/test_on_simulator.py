"""The CAV side on the lead's simulator (mmatch.sim.scenario): ego-motion and moving points vs labels."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.cav.egomotion import fit_egomotion
from mmatch.cav.process import run_view
from mmatch.codec import encode

scenario = pytest.importorskip("mmatch.sim.scenario")


@pytest.fixture(scope="module")
def observations():
    out = []
    for seed in range(24):
        mode = ("easy", "hard", "mixed")[seed % 3]
        sc = scenario.make_scenario(seed, mode)
        for role in ("ego", "cav"):
            t = 0.2 + 0.31 * seed % 9.0                       # inside episode 0
            o = sc.observe(role, t)
            parked = sc.world(int(t // scenario.EPISODE_S)).vehicles.parked
            gt = (o.point_labels >= 0) & ~parked[np.maximum(o.point_labels, 0)]
            out.append((o, gt))
    return out


def test_egomotion_recovers_the_simulated_radar_velocity(observations):
    errs, tp, fp, fn, false_stat, n_stat, no_estimate = [], 0, 0, 0, 0, 0, 0
    for o, gt in observations:
        e = fit_egomotion(o.points)
        if not e.ok:            # allowed only for frames with next to no stationary structure
            assert np.sum(o.point_labels == -1) < 10, e.reason
            no_estimate += 1
            continue
        errs.append(np.linalg.norm(e.velocity - o.velocity))
        tp += np.sum(e.moving & gt)
        fp += np.sum(e.moving & ~gt)
        fn += np.sum(~e.moving & gt)
        stat = o.point_labels == -1
        false_stat += np.sum(e.moving & stat)
        n_stat += stat.sum()
    errs = np.array(errs)
    assert no_estimate <= 0.1 * len(observations)
    print(f"\nsimulator, {len(observations)} frames ({no_estimate} without an estimate): |v err| median {np.median(errs):.3f} m/s, p90 "
          f"{np.percentile(errs, 90):.3f}, max {errs.max():.3f}; ego-motion stage moving recall "
          f"{tp / (tp + fn):.3f}, precision {tp / (tp + fp):.3f} (ghosts and clutter move too); "
          f"stationary structure called moving {false_stat / n_stat:.3f}")
    assert np.median(errs) <= 0.2
    assert np.percentile(errs, 90) <= 0.5
    assert tp / (tp + fn) >= 0.95
    assert false_stat / n_stat <= 0.05


def test_shared_vehicle_points_against_the_point_labels(observations):
    tp = fp = fn = fn_boxed = parked_right = parked_all = 0
    sizes, totals = [], []
    for o, gt in observations:
        out = run_view(o.points, o.boxes, o.features, o.camera, o.radar_height, o.stamp)
        pv = out.point_vehicle
        shared = pv >= 0
        called_moving = shared & np.append(out.vehicle_moving, False)[pv]     # pv -1 -> False
        boxed = np.isin(o.point_labels, o.box_ids[o.box_ids >= 0])
        tp += np.sum(called_moving & gt)
        fp += np.sum(called_moving & ~gt)
        fn += np.sum(~called_moving & gt)
        fn_boxed += np.sum(~called_moving & gt & boxed)
        parked_pts = shared & ~called_moving
        truth = np.append(o.box_ids[out.frame.vehicle_box_index], -9)[pv]   # true vehicle of the box
        parked_right += np.sum(parked_pts & (o.point_labels == truth))
        parked_all += np.sum(parked_pts)
        sizes.append(len(encode(out.frame)))
        totals.append(sum(out.timings.values()))
    precision, recall, recall_boxed = tp / (tp + fp), tp / (tp + fn), tp / (tp + fn_boxed)
    print(f"\nsimulator, {len(observations)} frames: moving-vehicle points precision {precision:.3f}, "
          f"recall {recall:.3f} (of all moving-vehicle points; {recall_boxed:.3f} of those on vehicles "
          f"the camera detected); parked-vehicle points on their box's vehicle {parked_right / parked_all:.3f}; "
          f"encoded frame median {np.median(sizes):.0f} B, max {max(sizes)} B; "
          f"CAV-side time median {np.median(totals):.1f} ms")
    assert precision >= 0.9
    assert recall_boxed >= 0.85
    assert recall >= 0.5            # the camera (+-33 deg) sees less than the radar (+-60 deg)
    assert parked_right / parked_all >= 0.4
    assert max(sizes) <= 9 * 1024


def test_the_order_of_the_points_does_not_change_the_fit(observations):
    """TI lists points by range, other code as it likes: the RANSAC draws from a canonical order,
    so a simulated frame listed backwards or shuffled fits the same velocity and flags the same
    points (before, 82 of 400 wide-physics views differed, by up to 9 mm/s and one background
    point of the shared sketch)."""
    for k, (o, _) in enumerate(observations):
        e = fit_egomotion(o.points)
        for perm in (np.arange(len(o.points))[::-1], np.random.default_rng(k).permutation(len(o.points))):
            e2 = fit_egomotion(o.points[perm])
            assert e2.ok == e.ok
            np.testing.assert_allclose(e2.velocity, e.velocity, rtol=0, atol=1e-9)
            np.testing.assert_array_equal(e2.moving, e.moving[perm])
