"""`mmatch eval --sequences`: a tracking fuser per sequence beside the per-frame mode."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from mmatch.edge.cli import main
from mmatch.sequence_eval import over_time


def test_eval_sequences_reports_both_modes_side_by_side(short_sequences, tmp_path, capsys):
    folder, scenes = short_sequences
    out = tmp_path / "seq.json"
    assert main(["eval", str(folder), "--sequences", "--json", str(out)]) == 0
    table = capsys.readouterr().out
    assert "tracked" in table and "per-frame" in table and "first estimate" in table
    rep = json.loads(out.read_text())
    assert rep["sequences"] == 2 and rep["frames"] == 24 and rep["rejected"] == 0
    for mode in ("tracked", "per_frame"):
        r = rep[mode]
        assert r["scenes"] == 24
        assert set(r["over_time"]) >= {"time_to_first_estimate_s", "recovery_s", "gross_frame_share"}
        assert 0.0 <= r["over_time"]["gross_frame_share"] <= r["coverage"]
    # the fused object tracks against the truth: ids and co-visible velocities
    o = rep["tracked"]["objects"]
    assert "objects" not in rep["per_frame"] and o["frames"] == 24 and o["objects"] > 24
    assert o["matched_share"] > 0.8 and o["id_switches_per_100_frames"] <= 10
    assert o["velocity_error_mps"]["n"] > 10 and o["velocity_error_mps"]["median"] < 1.0
    assert "id switches" in table
    frames = json.loads(out.with_suffix(".frames.json").read_text())
    # every frame once per mode, in frame order within its sequence
    for mode in ("tracked", "per_frame"):
        rows = frames[mode]
        assert len(rows) == 24
        for seq in {r["sequence"] for r in rows}:
            ks = [r["frame"] for r in rows if r["sequence"] == seq]
            assert ks == sorted(ks) == list(range(12))
    # the per-frame mode is `mmatch eval` on the same files
    plain = tmp_path / "plain.json"
    assert main(["eval", str(folder), "--json", str(plain)]) == 0
    rows = {r["scene"]: r for r in json.loads(plain.with_suffix(".scenes.json").read_text())}
    for r in frames["per_frame"]:
        assert r["status"] == rows[r["scene"]]["status"] and r["T_ego_cav"] == rows[r["scene"]]["T_ego_cav"]


def test_files_outside_a_sequence_are_rejected_and_named(short_sequences, tmp_path, capsys):
    folder, _ = short_sequences
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for f in sorted(folder.glob("*.npz"))[:3]:
        shutil.copy(f, mixed / f.name)
    from mmatch.sim.generate import generate
    generate(mixed, 1, seed=3, mode="easy")                       # an independent scene: no meta.sequence
    (mixed / "broken.npz").write_bytes(b"not a zip")
    assert main(["eval", str(mixed), "--sequences"]) == 0
    err = capsys.readouterr().err
    assert "broken.npz" in err and "scene_00000.npz" in err and "sequence" in err


def test_figures_over_time():
    def row(seq, k, status, rre=None, rte=None, success=False):
        return {"sequence": seq, "frame": k, "stamp": 0.05 * k, "status": status, "rre_deg": rre, "rte_m": rte,
                "success": success}
    rows = [row("a", 0, "no-estimate"), row("a", 1, "no-estimate"), row("a", 2, "fused", 1.0, 0.5, True),
            row("a", 3, "fused", 30.0, 9.0), row("a", 4, "fused", 20.0, 1.0), row("a", 5, "fused", 1.0, 0.5, True),
            row("b", 0, "no-estimate"), row("b", 1, "fused", 40.0, 20.0)]
    t = over_time(rows)
    assert t["time_to_first_estimate_s"]["median"] == pytest.approx(0.075)      # 0.1 s and 0.05 s
    assert t["recovery_s"]["n"] == 1 and t["recovery_s"]["max"] == pytest.approx(0.1)
    assert t["unrecovered"] == 1 and t["gross_runs"] == 2
    assert t["gross_frame_share"] == pytest.approx(3 / 8)
    assert np.isclose(t["frames"], 8)


def test_tracked_pairs_are_those_the_published_transform_implies(short_sequences):
    """With tracking too, a fused result's pairs are the matcher's assignment under the transform
    it publishes (RM-net's for the default matcher), whether the frame was searched or tracked."""
    from mmatch.ego.observations import observations_shared
    from mmatch.evaluate import prepare_scene
    from mmatch.scene_io import load_scene
    from mmatch.sequence_eval import SequenceEvalConfig, group_sequences, tracking_fuser
    folder, _ = short_sequences
    groups, _ = group_sequences(sorted(str(p) for p in folder.glob("*.npz")))
    checked = 0
    for items in groups.values():
        fuser = tracking_fuser(SequenceEvalConfig())          # one per drive, as `--sequences` runs it
        for _, path in items:
            own, other, _, _ = prepare_scene(load_scene(path))
            res = fuser.fuse(own, other)
            if res.status != "fused":
                continue
            T = res.T_ego_cav
            with observations_shared():
                expected = fuser.matcher.pairs_under(own, other, T[:2, :2], T[:2, 3])
            np.testing.assert_array_equal(res.pairs, expected, err_msg=path)
            checked += 1
    assert checked >= 8
