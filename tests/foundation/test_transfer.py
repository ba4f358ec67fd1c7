"""Transfer checks: each rewrite does what it says, invariances hold, the command reports them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmatch.edge.cli import main
from mmatch.errors import ConfigError
from mmatch.scene_io import load_scene
from mmatch.shared import SharedFrame, with_canonical_background
from mmatch.sim.generate import generate
from mmatch.transfer import CHECKS, markdown, parse_checks, perturb, run_transfer


@pytest.fixture(scope="module")
def wide_hard_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("wide-hard")
    generate(out, 80, seed=17, mode="hard", jobs=1, physics="wide")
    return out


def test_each_check_rewrites_both_views_as_described(hard_dir):
    s = load_scene(sorted(hard_dir.glob("*.npz"))[0])
    before = {k: np.array(getattr(s.ego, k)) for k in ("points", "boxes")}
    big = perturb(s, CHECKS["resolution-2x"])
    np.testing.assert_allclose(big.cav.camera.K[:2], 2 * s.cav.camera.K[:2])
    np.testing.assert_allclose(big.ego.boxes[:, :4], 2 * s.ego.boxes[:, :4])
    np.testing.assert_array_equal(big.ego.boxes[:, 4:], s.ego.boxes[:, 4:])
    assert big.ego.camera.image_size == (2 * s.ego.camera.image_size[0], 2 * s.ego.camera.image_size[1])
    shuffled = perturb(s, CHECKS["point-order"])
    assert not np.array_equal(shuffled.ego.points, s.ego.points)
    rows = lambda v: sorted(map(tuple, np.column_stack([v.points, v.point_labels])))  # noqa: E731
    assert rows(shuffled.ego) == rows(s.ego) and rows(shuffled.cav) == rows(s.cav)
    moved = perturb(s, CHECKS["box-order"])
    assert not np.array_equal(moved.cav.boxes, s.cav.boxes)
    assert len(s.gt_pairs) >= 1
    for (a, b), (a2, b2) in zip(s.gt_pairs, moved.gt_pairs):      # the true pairs follow their boxes
        np.testing.assert_array_equal(moved.ego.boxes[a2], s.ego.boxes[a])
        np.testing.assert_array_equal(moved.cav.features[b2], s.cav.features[b])
        assert moved.cav.box_ids[b2] == s.cav.box_ids[b]
    half = perturb(s, CHECKS["half-points"])
    assert 0.3 < len(half.ego.points) / len(s.ego.points) < 0.7
    assert set(map(tuple, half.ego.points)) <= set(map(tuple, s.ego.points))
    assert len(half.ego.point_labels) == len(half.ego.points)
    np.testing.assert_allclose(perturb(s, CHECKS["scores-0.6"]).cav.boxes[:, 4], 0.6 * s.cav.boxes[:, 4], rtol=1e-6)
    np.testing.assert_allclose(perturb(s, CHECKS["depth-0.85"]).ego.boxes[:, 5], 0.85 * s.ego.boxes[:, 5], rtol=1e-6)
    near = perturb(s, CHECKS["depth-near-face"]).ego.boxes[:, 5]
    np.testing.assert_allclose(near, np.maximum(s.ego.boxes[:, 5] - 2.0, 1.0), rtol=1e-6)
    axis = perturb(s, CHECKS["depth-z"]).cav.boxes[:, 5] / s.cav.boxes[:, 5]
    u = (s.cav.boxes[:, 0] + s.cav.boxes[:, 2]) / 2 - s.cav.camera.K[0, 2]
    np.testing.assert_allclose(axis, s.cav.camera.K[0, 0] / np.hypot(u, s.cav.camera.K[0, 0]), rtol=1e-5)
    assert axis.min() < 0.99
    dense = perturb(s, CHECKS["double-points"]).ego
    n = len(s.ego.points)
    assert len(dense.points) == 2 * n and np.array_equal(dense.points[:n], s.ego.points)
    np.testing.assert_array_equal(dense.point_labels, np.tile(s.ego.point_labels, 2))
    gap = np.linalg.norm(dense.points[n:, :2] - s.ego.points[:, :2], axis=1)
    assert 0.05 < np.median(gap) < 1.0
    noisy = perturb(s, CHECKS["azimuth+1.5deg"]).ego.points
    np.testing.assert_allclose(np.hypot(noisy[:, 0], noisy[:, 1]), np.hypot(s.ego.points[:, 0], s.ego.points[:, 1]),
                               rtol=1e-4)
    turn = np.degrees(np.arctan2(noisy[:, 0], noisy[:, 1]) - np.arctan2(s.ego.points[:, 0], s.ego.points[:, 1]))
    assert 0.8 < np.std(turn) < 2.5
    np.testing.assert_array_equal(noisy[:, 2:], s.ego.points[:, 2:])
    np.testing.assert_allclose(perturb(s, CHECKS["snr-6"]).ego.points[:, 4], s.ego.points[:, 4] - 6, atol=1e-5)
    assert not perturb(s, CHECKS["no-elevation"]).cav.points[:, 2].any()
    vague = perturb(s, CHECKS["descriptor-noise"])
    for view, orig in ((vague.ego, s.ego), (vague.cav, s.cav)):
        for lo, hi in ((0, 16), (16, 24), (24, 32)):      # each histogram keeps its mass, half of it redrawn
            np.testing.assert_allclose(view.features[:, lo:hi].sum(axis=1), orig.features[:, lo:hi].sum(axis=1),
                                       rtol=1e-5)
        moved_mass = np.abs(view.features - orig.features).sum(axis=1) / np.abs(orig.features).sum(axis=1)
        assert np.all(moved_mass > 0.05) and np.all(moved_mass < 1.0)
        assert view.features.min() >= 0
    hue = perturb(s, CHECKS["hue+1bin"])
    np.testing.assert_allclose(hue.ego.features[:, :16], np.roll(s.ego.features[:, :16], 1, axis=1))
    np.testing.assert_array_equal(hue.ego.features[:, 16:], s.ego.features[:, 16:])
    np.testing.assert_array_equal(hue.cav.features, s.cav.features)       # one camera unlike the other
    many = perturb(s, CHECKS["8x-points"]).cav
    assert len(many.points) == 8 * len(s.cav.points) and np.array_equal(many.points[:len(s.cav.points)], s.cav.points)
    assert len(many.point_labels) == len(many.points)
    assert not perturb(s, CHECKS["no-depth"]).cav.boxes[:, 5].any()
    blank = perturb(s, CHECKS["no-colour"])
    assert not blank.ego.features.any() and not blank.cav.features.any()
    # repeatable, and the scene itself untouched
    np.testing.assert_array_equal(perturb(s, CHECKS["half-points"]).cav.points, half.cav.points)
    for k, v in before.items():
        np.testing.assert_array_equal(getattr(s.ego, k), v)


def test_the_background_checks_change_the_stationary_world_only(hard_dir):
    """half-background and double-background thin or repeat the labelled stationary returns (label
    -1) and leave every vehicle's, clutter's and ghost's; a file without labels has its stationary
    returns found by its own ego-motion fit."""
    from dataclasses import replace

    from mmatch.cav.egomotion import fit_egomotion
    s = load_scene(sorted(hard_dir.glob("*.npz"))[0])
    half = perturb(s, CHECKS["half-background"])
    for view, orig in ((half.ego, s.ego), (half.cav, s.cav)):
        still = orig.point_labels == -1
        assert 0.3 < (view.point_labels == -1).sum() / still.sum() < 0.7
        np.testing.assert_array_equal(view.points[view.point_labels != -1], orig.points[~still])
        assert set(map(tuple, view.points)) <= set(map(tuple, orig.points))
    dense = perturb(s, CHECKS["double-background"]).cav
    still = s.cav.point_labels == -1
    n = len(s.cav.points)
    assert len(dense.points) == n + still.sum() and np.array_equal(dense.points[:n], s.cav.points)
    np.testing.assert_array_equal(dense.point_labels[n:], -1)
    gap = np.linalg.norm(dense.points[n:, :2] - s.cav.points[still, :2], axis=1)
    assert 0.02 < np.median(gap) < 0.15
    np.testing.assert_array_equal(dense.points[n:, 2:], s.cav.points[still, 2:])
    unlabelled = replace(s, ego=replace(s.ego, point_labels=None), cav=replace(s.cav, point_labels=None))
    thin = perturb(unlabelled, CHECKS["half-background"]).ego
    kept = {tuple(p) for p in thin.points}
    moving = fit_egomotion(s.ego.points).moving
    assert moving.sum() >= 5 and all(tuple(p) in kept for p in s.ego.points[moving])
    assert 0.3 < np.mean([tuple(p) in kept for p in s.ego.points[~moving]]) < 0.7


def test_each_frame_votes_for_the_doppler_sign_its_radar_motion_explains(hard_dir):
    """cav/doppler_sign.py: a moving radar's frame fits DESIGN.md's sign, the same frame negated
    the other one; a folder flips only when nearly all of at least MIN_FRAMES votes say so."""
    from mmatch.cav.doppler_sign import MIN_FRAMES, judge_sign, sign_vote, with_sign
    from mmatch.evaluate import folder_doppler_sign
    files = sorted(str(f) for f in hard_dir.glob("*.npz"))[:6]
    views = [v for f in files for v in (load_scene(f).ego, load_scene(f).cav)]
    votes = np.array([sign_vote(v.points) for v in views])
    flipped = np.array([sign_vote(with_sign(v.points, -1)) for v in views])
    assert np.all(votes[np.isfinite(votes)] == 1) and np.isfinite(votes).sum() >= MIN_FRAMES
    np.testing.assert_array_equal(flipped, -votes)
    assert judge_sign(votes) == 1 and judge_sign(flipped) == -1
    assert judge_sign(flipped[:MIN_FRAMES - 1]) == 1                       # too few to say
    assert judge_sign(list(flipped[:9]) + [1.0, 1.0]) == 1                # not nearly all
    assert folder_doppler_sign(files) == 1


def test_eval_reads_a_folder_of_the_other_doppler_sign_as_it_reads_ours(hard_dir, tmp_path):
    """`mmatch eval` judges the sign on the folder: a copy with every Doppler negated gives the
    same per-scene results; told the sign (EvalConfig.doppler_sign = 1), it reads it as given."""
    from mmatch.evaluate import EvalConfig, evaluate_dir
    from mmatch.scene_io import save_scene
    for f in sorted(hard_dir.glob("*.npz"))[:6]:
        sc = load_scene(f)
        save_scene(tmp_path / f.name, perturb(sc, CHECKS["doppler-sign"]))
    src = tmp_path / "src"
    src.mkdir()
    for f in sorted(hard_dir.glob("*.npz"))[:6]:
        (src / f.name).write_bytes(f.read_bytes())
    keys = ("status", "box_pairs", "T_ego_cav", "confidence")
    _, ours = evaluate_dir(src)
    rep, theirs = evaluate_dir(tmp_path)
    assert [tuple(r[k] for k in keys) for r in ours] == [tuple(r[k] for k in keys) for r in theirs]
    assert rep["config"]["doppler_sign"] == -1
    _, forced = evaluate_dir(tmp_path, EvalConfig(doppler_sign=1))
    assert [tuple(r[k] for k in keys) for r in forced] != [tuple(r[k] for k in keys) for r in ours]


def test_unknown_checks_are_refused_by_name():
    assert parse_checks("point-order, scores-0.6") == ["point-order", "scores-0.6"]
    with pytest.raises(ConfigError, match="--checks: unknown.*'colour'"):
        parse_checks("colour")


def test_invariances_hold_and_shifts_are_measured(hard_dir, tmp_path):
    """The same estimates through a camera of twice the resolution and with the radar points in
    another order, with our CAV side and with perfect separation (whose background reaches the
    Ego in the scene file's order: the Ego reads it in its canonical order)."""
    out = run_transfer(hard_dir, ["resolution-2x", "point-order", "doppler-sign", "half-points"], max_scenes=6)
    assert out["scenes"] == 6
    assert list(out["checks"]) == ["none", "resolution-2x", "point-order", "doppler-sign", "half-points"]
    for name in ("resolution-2x", "point-order", "doppler-sign"):
        e = out["checks"][name]
        assert e["kind"] == "invariance"
        assert e["pipeline"]["changed_scenes"] == 0 and e["labels"]["changed_scenes"] == 0, (name, e)
        # the same figures (a confidence may move in its last bits: the calibration error is a sum)
        assert e["pipeline"] == pytest.approx(dict(out["checks"]["none"]["pipeline"], changed_scenes=0), rel=1e-9)
    half = out["checks"]["half-points"]["pipeline"]
    assert half["changed_scenes"] > 0 and 0 <= half["pair_f1"] <= 1 and 0 <= half["success_rate"] <= 1
    assert 0 <= half["gross_rate"] <= 1 and 0 <= half["calibration_error"] <= 1


def test_the_table_says_how_sure_each_check_leaves_the_output():
    """A shift can leave pair F1 alone and still make the confidence lie: the table carries the
    pipeline's coverage, gross rate among the emitted and calibration error beside F1."""
    def block(f1: float, cov: float, gross: float, ece: float) -> dict:
        return {"scenes": 10, "rejected": 0, "pair_f1": f1, "success_rate": 0.5, "coverage": cov,
                "gross_rate": gross, "gross_at_0.8": 0.1, "calibration_error": ece, "changed_scenes": 3}
    result = {"scenes": 10, "checks": {
        "none": {"kind": "reference", "pipeline": block(0.9, 0.8, 0.0, 0.05), "labels": block(0.95, 0.8, 0.0, 0.04)},
        "half-points": {"kind": "shift", "pipeline": block(0.88, 0.7, 0.125, 0.2),
                        "labels": dict(block(0.9, 0.7, 0.0, 0.1), scenes=0)}}}
    rows = markdown(result).splitlines()
    assert "gross among emitted / calibration error" in rows[0] and rows[1].count("---") == 8
    half = rows[3].split(" | ")
    assert half[4] == "-2.0" and half[5] == "0.70 / 0.125 / 0.200" and half[2] == "0.880 / 0.500"
    assert half[3] == "-"                                   # perfect separation ran on no scene


def test_invariances_hold_on_wide_hard_scenes(wide_hard_dir):
    """The gate on what the physics family does not vary: 80 wide hard scenes through a camera
    of twice the resolution, with their points shuffled, with their detections shuffled and with
    their Doppler of the other sign (judged on the folder) give the same status, pairs and
    transform in every scene, with our CAV side and with perfect separation."""
    out = run_transfer(wide_hard_dir, ["resolution-2x", "point-order", "box-order", "doppler-sign"], jobs=2)
    for name in ("resolution-2x", "point-order", "box-order", "doppler-sign"):
        e = out["checks"][name]
        assert (e["pipeline"]["changed_scenes"], e["labels"]["changed_scenes"]) == (0, 0), (name, e)


def test_the_ego_reads_a_background_in_one_order():
    rng = np.random.default_rng(3)
    bg = rng.uniform(-40, 40, (300, 3)).astype(np.float32)
    frame = SharedFrame(sender="cav", seq=1, stamp=0.0, radar_height=0.5, background=bg)
    a = with_canonical_background(frame)
    b = with_canonical_background(SharedFrame(sender="cav", seq=1, stamp=0.0, radar_height=0.5,
                                              background=bg[rng.permutation(300)]))
    np.testing.assert_array_equal(a.background, b.background)
    assert with_canonical_background(a) is a                       # in order already: no copy
    assert sorted(map(tuple, a.background)) == sorted(map(tuple, bg))


def test_the_command_prints_the_table_and_writes_json(hard_dir, tmp_path, capsys):
    out = tmp_path / "transfer.json"
    assert main(["transfer", str(hard_dir), "--checks", "point-order,scores-0.6", "--scenes", "3",
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| point-order | invariance |" in text and "(holds)" in text and "| scores-0.6 | shift |" in text
    data = json.loads(out.read_text())
    assert data["scenes"] == 3 and set(data["checks"]) == {"none", "point-order", "scores-0.6"}
    assert main(["transfer", str(hard_dir), "--checks", "nonsense"]) == 2
    assert "--checks: unknown" in capsys.readouterr().err
    assert main(["transfer", str(tmp_path / "missing")]) == 2


def test_a_broken_invariance_is_reported_and_fails_the_command(hard_dir, monkeypatch, capsys):
    """An "invariance" that does change the answer (here: every camera depth halved) must show as
    BROKEN and make the command exit 1, so that CI can run it as a gate."""
    import mmatch.transfer as T

    halve = T.Check("depth-halved", "invariance", "not an invariance at all", T._box_column(5, 0.5))
    monkeypatch.setitem(T.CHECKS, halve.name, halve)
    out = run_transfer(hard_dir, ["depth-halved"], max_scenes=4)
    assert out["checks"]["depth-halved"]["pipeline"]["changed_scenes"] > 0
    assert main(["transfer", str(hard_dir), "--checks", "depth-halved", "--scenes", "4"]) == 1
    assert "(BROKEN)" in capsys.readouterr().out


def test_files_that_are_no_scene_or_have_no_labels_are_counted_not_fatal(hard_dir, tmp_path, capsys):
    """A folder from elsewhere: one good scene, one scene without labels (perfect separation
    cannot run on it), one file that is no scene. Each check runs on what it can."""
    from dataclasses import replace

    from mmatch.scene_io import save_scene

    folder = tmp_path / "mixed"
    folder.mkdir()
    good = sorted(hard_dir.glob("*.npz"))[:2]
    (folder / "a.npz").write_bytes(good[0].read_bytes())
    s = load_scene(good[1])
    bare = replace(s, ego=replace(s.ego, point_labels=None, box_ids=None),
                   cav=replace(s.cav, point_labels=None, box_ids=None))
    save_scene(folder / "b.npz", bare)
    (folder / "c.npz").write_bytes(b"not a scene at all")
    out = run_transfer(folder, ["point-order"])
    ref = out["checks"]["none"]
    assert out["scenes"] == 3
    assert (ref["pipeline"]["scenes"], ref["pipeline"]["rejected"]) == (2, 1)
    assert (ref["labels"]["scenes"], ref["labels"]["rejected"]) == (1, 2)
    assert out["checks"]["point-order"]["pipeline"]["changed_scenes"] == 0
    assert main(["transfer", str(folder), "--checks", "point-order"]) == 0
    assert "3 scene files, 1 rejected (2 for perfect separation" in capsys.readouterr().out
