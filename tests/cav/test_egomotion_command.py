"""`mmatch egomotion DIR --json FILE` on mmatch-radar/1 files, good and bad."""

from __future__ import annotations

import json

import numpy as np

from mmatch.edge.cli import main
from mmatch.scene_io import RADAR_FORMAT, save_radar_frame

from .synth import make_frame


def run_command(argv: list[str]) -> int:
    """The command as `mmatch egomotion ...` runs it (errors become exit codes there)."""
    return main(["egomotion", *argv])


def write_bad(path, **arrays):
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)


def test_report_matches_design_and_bad_files_are_named(tmp_path, capsys):
    truth = {}
    for i in range(6):
        f = make_frame(100 + i)
        save_radar_frame(tmp_path / f"f{i}.npz", f.points, f.velocity, f.gt_moving)
        truth[f"f{i}.npz"] = f
    save_radar_frame(tmp_path / "nogt.npz", make_frame(7).points)
    pts = make_frame(8).points
    write_bad(tmp_path / "bad_missing.npz", format=np.array(RADAR_FORMAT))
    write_bad(tmp_path / "bad_shape.npz", format=np.array(RADAR_FORMAT), points=pts[:, :4])
    nan = pts.copy()
    nan[3, 2] = np.nan
    write_bad(tmp_path / "bad_nan.npz", format=np.array(RADAR_FORMAT), points=nan)
    write_bad(tmp_path / "bad_moving.npz", format=np.array(RADAR_FORMAT), points=pts,
              gt_moving=np.zeros(len(pts) - 1, bool))
    (tmp_path / "bad_not_npz.npz").write_bytes(b"not a zip file")
    write_bad(tmp_path / "degenerate.npz", format=np.array(RADAR_FORMAT), points=pts[:2])

    out = tmp_path / "out" / "ego.json"
    assert run_command([str(tmp_path), "--json", str(out)]) == 0
    captured = capsys.readouterr()
    for name, key in [("bad_missing", "points"), ("bad_shape", "points"), ("bad_nan", "points"),
                      ("bad_moving", "gt_moving"), ("bad_not_npz", "<file>")]:
        line = next(ln for ln in captured.err.splitlines() if f"{name}.npz" in ln)
        assert f"'{key}'" in line and line.startswith("rejected:")
    assert "no estimate: degenerate.npz: too-few-points" in captured.err

    r = json.loads(out.read_text())
    assert list(r) == ["frames", "rejected", "velocity_error_mps", "moving_precision",
                       "moving_recall", "per_frame"]
    assert r["frames"] == 8 and r["rejected"] == 5
    assert set(r["velocity_error_mps"]) == {"median", "p90"}
    assert r["velocity_error_mps"]["median"] <= 0.2
    assert 0.5 <= r["moving_precision"] <= 1.0 and r["moving_recall"] >= 0.9
    by_file = {e["file"]: e for e in r["per_frame"]}
    assert set(by_file) == set(truth) | {"nogt.npz", "degenerate.npz"}
    assert by_file["degenerate.npz"]["velocity"] == [None, None] and by_file["degenerate.npz"]["moving"] == []
    for name, f in truth.items():
        e = by_file[name]
        assert set(e) == {"file", "velocity", "moving"}
        assert np.linalg.norm(np.array(e["velocity"]) - f.velocity) < 0.5
        moving = np.zeros(len(f.points), bool)
        moving[e["moving"]] = True
        assert np.mean(f.gt_moving[moving]) > 0.4           # mostly real movers (ghosts move too)
    assert "frames 8  rejected 5" in captured.out


def test_folder_without_ground_truth_gives_null_figures(tmp_path, capsys):
    save_radar_frame(tmp_path / "a.npz", make_frame(1).points)
    out = tmp_path / "e.json"
    assert run_command([str(tmp_path), "--json", str(out), "--threshold", "0.5"]) == 0
    r = json.loads(out.read_text())
    assert r["frames"] == 1 and r["velocity_error_mps"] == {"median": None, "p90": None}
    assert r["moving_precision"] is None and r["moving_recall"] is None


def test_missing_folder_is_an_error(tmp_path, capsys):
    assert run_command([str(tmp_path / "nope")]) == 2
    assert "not a folder" in capsys.readouterr().err
