"""Camera depth calibration: a monocular detector whose depths are all off by one factor."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmatch.cav.depth_scale import (
    CONTENT_BAND,
    MIN_BOXES,
    RUNNING_MIN_BOXES,
    SCALE_LIMITS,
    TYPICAL_LOG_RATIO,
    RunningDepthScale,
    DepthCalibration,
    along_axis,
    box_depth_evidence,
    calibrate,
    scale_from_ratios,
)
from mmatch.cav.frustum import project
from mmatch.cav.process import CavInputError, ViewProcessor, depth_evidence, process_view, run_view
from mmatch.edge.cli import main
from mmatch.evaluate import EvalConfig, depth_calibrations, evaluate_dir, folder_depth_calibration, scene_depth_evidence
from mmatch.scene_io import load_scene, save_scene
from mmatch.transfer import CHECKS, perturb, run_transfer


def _scaled_depths(view, factor: float):
    boxes = np.array(view.boxes, np.float32)
    boxes[:, 5] *= factor
    view.boxes = boxes
    return view


@pytest.fixture(scope="module")
def short_dir(hard_dir, tmp_path_factory):
    """The 30 nominal hard scenes through a detector that puts every vehicle 15 % too near."""
    out = tmp_path_factory.mktemp("short-depth")
    for f in sorted(hard_dir.glob("*.npz")):
        s = load_scene(f)
        _scaled_depths(s.ego, 0.85)
        _scaled_depths(s.cav, 0.85)
        save_scene(out / f.name, s)
    return out


def test_scale_from_ratios_corrects_only_beyond_the_content_band():
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.08, 400)
    assert scale_from_ratios(TYPICAL_LOG_RATIO + noise) == 1.0
    assert scale_from_ratios(TYPICAL_LOG_RATIO + 0.9 * CONTENT_BAND + noise * 0.01) == 1.0
    far = TYPICAL_LOG_RATIO + np.log(1 / 0.85) + noise * 0.01          # every depth 15 % short
    assert scale_from_ratios(far) == pytest.approx(np.exp(np.log(1 / 0.85) - CONTENT_BAND), rel=0.01)
    near = TYPICAL_LOG_RATIO - np.log(1.15) + noise * 0.01               # 15 % long
    assert scale_from_ratios(near) == pytest.approx(np.exp(-np.log(1.15) + CONTENT_BAND), rel=0.01)
    assert scale_from_ratios(far[:MIN_BOXES - 1]) == 1.0                # too few boxes say nothing
    assert scale_from_ratios(np.full(500, 5.0)) == SCALE_LIMITS[1]
    assert scale_from_ratios([]) == 1.0


def test_box_ratios_follow_the_depths_and_ignore_stationary_returns(hard_dir):
    s = load_scene(sorted(hard_dir.glob("*.npz"))[0])
    v = s.ego
    products = run_view(v.points, v.boxes, v.features, v.camera, v.radar_height, v.stamp)
    proj = project(v.points[:, :3], v.camera)
    moving = np.zeros(len(v.points), bool)
    moving[products.rows] = products.ego.moving
    ev = box_depth_evidence(v.boxes, proj, moving, v.camera.K)
    np.testing.assert_allclose(ev, products.depth_evidence)
    np.testing.assert_array_equal(depth_evidence(v.points, v.boxes, v.features, v.camera), products.depth_evidence)
    base = ev[:, 0]
    assert len(base) >= 2 and np.all(np.abs(base) < 1.0)
    assert np.all(ev[:, 1] >= 0) and np.all(ev[:, 1] < 0.2)            # -log cos(bearing), inside the view
    near = np.array(v.boxes, np.float64)
    near[:, 5] *= 0.95                                  # inside the window: the same returns count
    np.testing.assert_allclose(box_depth_evidence(near, proj, moving, v.camera.K)[:, 0], base + np.log(1 / 0.95),
                               atol=0.05)
    assert len(box_depth_evidence(v.boxes, proj, np.zeros(len(v.points), bool), v.camera.K)) == 0
    assert len(box_depth_evidence(v.boxes, None, moving, v.camera.K)) == 0


def test_a_folder_of_calibrated_cameras_keeps_its_depths(hard_dir, tmp_path):
    files = sorted(str(f) for f in hard_dir.glob("*.npz"))
    assert [c.scale for c in folder_depth_calibration(files)] == [1.0, 1.0]
    rep, _ = evaluate_dir(hard_dir, EvalConfig())
    assert rep["config"]["depth_scale"] == [1.0, 1.0] or rep["config"]["depth_scale"] == (1.0, 1.0)


def test_depths_15_percent_short_are_calibrated_and_the_results_recovered(hard_dir, short_dir):
    """The folder's cameras are calibrated against their radars without labels: the scale brings
    the depths back to within the content band, and pair F1 and success come back to within a
    few points of the calibrated cameras' (on 200 wide hard scenes of seed 5: F1 0.870 -> 0.913
    against 0.918, `mmatch transfer`)."""
    se, sc = (c.scale for c in folder_depth_calibration(sorted(str(f) for f in short_dir.glob("*.npz"))))
    for s in (se, sc):                  # 1 / 0.85 = 1.18, less the band: 1.14 (30 scenes: +- 0.04)
        assert 1.05 < s < 1.2
    ref, _ = evaluate_dir(hard_dir, EvalConfig(), jobs=2)
    fixed, _ = evaluate_dir(short_dir, EvalConfig(depth_scale=(1.0, 1.0)), jobs=2)
    auto, _ = evaluate_dir(short_dir, EvalConfig(), jobs=2)

    def f1(r):
        return 2 * r["pair_precision"] * r["pair_recall"] / (r["pair_precision"] + r["pair_recall"])
    assert f1(auto) >= f1(fixed) + 0.05
    assert f1(auto) >= f1(ref) - 0.03 and auto["success_rate"] >= ref["success_rate"] - 0.1
    assert auto["success_rate"] > fixed["success_rate"]


def test_the_service_calibrates_over_its_frames(short_dir):
    """The vehicle service's CAV side: depths as detected until enough boxes have spoken, then
    corrected; the shared frames carry the corrected depths."""
    proc = ViewProcessor()
    views = [v for f in sorted(short_dir.glob("*.npz")) for v in (load_scene(f).ego, load_scene(f).cav)] * 2
    scales = []
    for v in views:
        frame, _ = proc(v.points, v.boxes, v.features, v.camera, v.radar_height, v.stamp)
        scales.append(proc.depth.scale)
    assert scales[0] == 1.0 and 1.05 < scales[-1] < 1.2
    v = views[-1]
    used = proc.depth.scale                             # the frames before calibrate this one
    frame, _ = proc(v.points, v.boxes, v.features, v.camera, v.radar_height, v.stamp)
    plain, _ = process_view(v.points, v.boxes, v.features, v.camera, v.radar_height, v.stamp)
    common = np.intersect1d(frame.vehicle_box_index, plain.vehicle_box_index)
    assert len(common)
    got = frame.vehicle_boxes[np.searchsorted(frame.vehicle_box_index, common), 5]
    raw = plain.vehicle_boxes[np.searchsorted(plain.vehicle_box_index, common), 5]
    np.testing.assert_allclose(got, raw * used, rtol=1e-5)


def _ev(ratios, axis=0.0):
    r = np.asarray(ratios, float)
    return np.column_stack([r, np.broadcast_to(axis, r.shape)])


def test_running_scale_forgets_old_frames():
    assert RunningDepthScale().update(_ev(np.full(RUNNING_MIN_BOXES - 1, TYPICAL_LOG_RATIO + 0.3))).scale == 1.0
    run = RunningDepthScale(window=200, min_boxes=50)
    assert run.update(_ev(np.full(30, TYPICAL_LOG_RATIO + 0.3))).scale == 1.0          # too few yet
    assert run.update(_ev(np.full(30, TYPICAL_LOG_RATIO + 0.3))).scale > 1.2
    assert run.update(_ev(np.full(200, TYPICAL_LOG_RATIO))).scale == 1.0               # a recalibrated camera
    assert run.update(_ev([np.nan, np.inf])).scale == 1.0


def _axis_evidence(rng, n, slope):
    x = -np.log(np.cos(rng.uniform(-0.45, 0.45, n)))
    return np.column_stack([TYPICAL_LOG_RATIO + slope * x + rng.normal(0.0, 0.1, n), x])


def test_depths_along_the_optical_axis_are_recognised_and_turned_into_distances(hard_dir):
    rng = np.random.default_rng(4)
    assert along_axis(_axis_evidence(rng, 3000, 1.0)) and not along_axis(_axis_evidence(rng, 3000, 0.0))
    assert not along_axis(_axis_evidence(rng, 500, 1.0))                     # too few boxes to judge
    cal = calibrate(_axis_evidence(rng, 3000, 1.0))
    assert cal.along_axis and cal.scale == 1.0                               # distances once turned
    # a folder's two cameras judged together: the same scenes with depths along the axis
    scenes = [load_scene(f) for f in sorted(hard_dir.glob("*.npz"))]
    plain = [scene_depth_evidence(s) for s in scenes] * 5               # as many boxes as a big folder
    axis = [scene_depth_evidence(perturb(s, CHECKS["depth-z"])) for s in scenes] * 5
    assert [c.along_axis for c in depth_calibrations(plain)] == [False, False]
    assert [c.along_axis for c in depth_calibrations(axis)] == [True, True]
    # and the calibration gives back the distances the detector's convention hid
    s = scenes[0]
    z = perturb(s, CHECKS["depth-z"]).ego.boxes
    np.testing.assert_allclose(DepthCalibration(1.0, True).apply(z, s.ego.camera.K)[:, 5], s.ego.boxes[:, 5], rtol=1e-5)
    assert DepthCalibration().apply(z, s.ego.camera.K) is z


def test_the_eval_table_says_how_each_camera_was_calibrated():
    from mmatch.evaluate import format_table, report
    rep = report([], EvalConfig(depth_scale=(1.1, 1.0), depth_along_axis=(False, True)))
    assert "camera depth scales 1.100 / 1.000 (along the axis)" in format_table(rep)


def test_the_service_recognises_depths_along_the_axis_and_holds_its_judgement():
    rng = np.random.default_rng(5)
    run = RunningDepthScale(window=3000, judge_every=50)
    for _ in range(1000):
        run.update(_axis_evidence(rng, 4, 1.0))
    assert run.calibration.along_axis
    for _ in range(300):                                 # a noisy stretch does not flip it back
        run.update(_axis_evidence(rng, 4, 0.6))
    assert run.calibration.along_axis
    for _ in range(1000):                                # a camera that now gives distances does
        run.update(_axis_evidence(rng, 4, 0.0))
    assert not run.calibration.along_axis


def test_a_broken_scale_is_refused(hard_dir):
    v = load_scene(sorted(hard_dir.glob("*.npz"))[0]).ego
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(CavInputError, match="depth_scale"):
            process_view(v.points, v.boxes, v.features, v.camera, v.radar_height, v.stamp, depth_scale=bad)


def test_the_transfer_shift_is_calibrated(hard_dir):
    out = run_transfer(hard_dir, ["depth-0.85"], max_scenes=30)
    assert out["checks"]["none"]["depth_scale"] == [1.0, 1.0]
    assert all(1.05 < s < 1.2 for s in out["checks"]["depth-0.85"]["depth_scale"])


def test_cli_takes_a_depth_scale_and_refuses_a_bad_one(hard_dir, tmp_path, capsys):
    out = tmp_path / "rep.json"
    assert main(["eval", str(hard_dir), "--depth-scale", "1.1,0.9", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["config"]["depth_scale"] == [1.1, 0.9]
    for bad in ("0", "a", "1,2,3", "-1"):
        with pytest.raises(SystemExit):
            main(["eval", str(hard_dir), "--depth-scale", bad])
        assert "--depth-scale" in capsys.readouterr().err


def test_cli_takes_a_doppler_sign_and_refuses_a_bad_one(hard_dir, tmp_path, capsys):
    out = tmp_path / "rep.json"
    assert main(["eval", str(hard_dir), "--doppler-sign", "-1", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["config"]["doppler_sign"] == -1
    assert main(["eval", str(hard_dir), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["config"]["doppler_sign"] == 1             # judged: ours
    for bad in ("0", "2", "minus"):
        with pytest.raises(SystemExit):
            main(["eval", str(hard_dir), "--doppler-sign", bad])
        assert "--doppler-sign" in capsys.readouterr().err


def test_the_vehicle_service_reports_its_camera_depth_scale(short_dir):
    """The product pipeline's CAV side calibrates its camera, and the node's health says by how much."""
    from mmatch.edge import config
    from mmatch.edge.logschema import SensorFrame
    from mmatch.edge.node import Node
    from mmatch.edge.pipeline import default_pipeline

    cfg = config.VehicleConfig(vehicle=config.VehicleSection(id="cav1", role="cav"))
    views = [v for f in sorted(short_dir.glob("*.npz")) for v in (load_scene(f).ego, load_scene(f).cav)] * 2
    node = Node(cfg, default_pipeline(need_fuse=False), views[0].camera, views[0].radar_height)
    assert node.summary()["camera_depth_scale"] == 1.0
    for k, v in enumerate(views):
        node.process(SensorFrame(seq=k, stamp=float(k) * 0.05, points=v.points, boxes=v.boxes, features=v.features))
    assert 1.05 < node.summary()["camera_depth_scale"] < 1.2
    assert node.summary()["input_repairs"] == {"points_dropped": 0, "points_thinned": 0,
                                               "depths_by_size_prior": 0, "descriptors_rescaled": 0}
    v = views[0]
    boxes = v.boxes.copy()
    boxes[:, 5] = 0.0                                     # a detector without depths
    node.process(SensorFrame(seq=len(views), stamp=len(views) * 0.05, points=v.points, boxes=boxes,
                             features=v.features))
    assert node.summary()["input_repairs"]["depths_by_size_prior"] == len(boxes)


def test_frames_in_order_calibrate_as_the_service_does(short_dir):
    """`prepare_scene` with the cameras' processors (what `mmatch eval --sequences` runs): each
    camera's scale comes from the frames before, and the shared depths carry it."""
    from mmatch.evaluate import prepare_scene

    procs = (ViewProcessor(), ViewProcessor())
    scenes = [load_scene(f) for f in sorted(short_dir.glob("*.npz"))] * 3       # a road driven again
    for s in scenes:
        prepare_scene(s, EvalConfig(depth_scale=(1.0, 1.0)), procs)
    assert all(1.05 < p.depth.scale < 1.2 for p in procs)
    s = scenes[0]
    used = procs[1].depth.scale
    received = prepare_scene(s, EvalConfig(), procs)[1]
    plain = prepare_scene(s, EvalConfig(depth_scale=(1.0, 1.0)))[1]
    k = np.intersect1d(received.vehicle_box_index, plain.vehicle_box_index)
    got = received.vehicle_boxes[np.searchsorted(received.vehicle_box_index, k), 5]
    raw = plain.vehicle_boxes[np.searchsorted(plain.vehicle_box_index, k), 5]
    np.testing.assert_allclose(got, raw * used, atol=0.011)           # the wire keeps centimetres
