"""`mmatch compare`: two eval runs of the same scenes, scene by scene."""

from __future__ import annotations

import json

import pytest

from mmatch.compare import compare, load_rows, outcome, sign_test
from mmatch.edge.cli import main
from mmatch.errors import ConfigError


def _row(name: str, kind: str, tp: int = 1, folder: str = "/data/h1") -> dict:
    rows = {"right": ("fused", True, 1.0, 0.5), "off": ("fused", False, 3.0, 3.0),
            "gross": ("fused", False, 20.0, 1.0), "refused": ("no-estimate", False, None, None)}
    status, ok, rre, rte = rows[kind]
    return {"scene": name, "file": f"{folder}/{name}.npz", "status": status, "success": ok,
            "rre_deg": rre, "rte_m": rte, "tp": tp, "predicted": 2, "gt_pairs": 2}


def _write(path, rows: list[dict], frames: bool = False) -> str:
    report = path / "run.json"
    report.write_text(json.dumps({"scenes": len(rows)}))
    if frames:
        (path / "run.frames.json").write_text(json.dumps({"tracked": rows, "per_frame": []}))
    else:
        (path / "run.scenes.json").write_text(json.dumps(rows))
    return str(report)


def test_outcomes_follow_the_success_and_gross_definitions():
    assert [outcome(_row("s", k)) for k in ("right", "off", "gross", "refused")] == \
        ["right", "off", "gross", "refused"]
    assert outcome(dict(_row("s", "off"), rte_m=5.5)) == "gross"          # RTE beyond 5 m
    assert outcome(dict(_row("s", "off"), rte_m=5.0, rre_deg=10.0)) == "off"


def test_sign_test_is_exact_and_two_sided():
    assert sign_test(0, 0) == 1.0
    assert sign_test(5, 0) == pytest.approx(2 / 32)
    assert sign_test(0, 5) == pytest.approx(2 / 32)
    assert sign_test(10, 1) == pytest.approx(2 * 12 / 2048)
    assert sign_test(3, 2) == 1.0


def test_compare_counts_moves_and_paired_changes():
    a = {k: _row(k, kind) for k, kind in [("s1", "right"), ("s2", "refused"), ("s3", "refused"),
                                          ("s4", "gross"), ("s5", "off"), ("s6", "right")]}
    b = {k: _row(k, kind) for k, kind in [("s1", "right"), ("s2", "right"), ("s3", "gross"),
                                          ("s4", "refused"), ("s5", "right"), ("s7", "right")]}
    c = compare(a, b)
    assert (c["scenes"], c["only_a"], c["only_b"]) == (5, 1, 1)
    assert c["moves"] == {"gross->refused": 1, "off->right": 1, "refused->gross": 1, "refused->right": 1}
    assert c["right"] == {"gained": 2, "lost": 0, "p_value": pytest.approx(0.5)}
    assert c["gross"]["gained"] == 1 and c["gross"]["lost"] == 1
    assert c["a"]["success_rate"] == pytest.approx(1 / 5) and c["b"]["success_rate"] == pytest.approx(3 / 5)
    assert c["a"]["coverage"] == pytest.approx(3 / 5) and c["b"]["gross_rate"] == pytest.approx(1 / 4)


def test_runs_pair_up_by_folder_and_file_wherever_they_ran(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    ra = _write(tmp_path / "a", [_row("s1", "right", folder="/one/h1"), _row("s2", "refused", folder="/one/h1")])
    rb = _write(tmp_path / "b", [_row("s1", "right", folder="/two/h1"), _row("s2", "right", folder="/two/h1")],
                frames=True)
    c = compare(load_rows(ra), load_rows(rb))
    assert c["scenes"] == 2 and c["moves"] == {"refused->right": 1}
    pooled = load_rows([ra, rb])                   # the same scenes twice: one entry each
    assert sorted(pooled) == ["h1/s1.npz", "h1/s2.npz"]


def test_missing_or_broken_per_scene_results_name_the_file(tmp_path):
    report = tmp_path / "run.json"
    report.write_text("{}")
    with pytest.raises(ConfigError, match="run.scenes.json"):
        load_rows(report)
    (tmp_path / "run.scenes.json").write_text("[{\"no scene\": 1}")
    with pytest.raises(ConfigError, match="unreadable"):
        load_rows(report)


def test_cli_prints_and_writes_the_comparison(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    ra = _write(tmp_path / "a", [_row(f"s{i}", "refused") for i in range(6)])
    rb = _write(tmp_path / "b", [_row(f"s{i}", "right") for i in range(6)])
    out = tmp_path / "cmp.json"
    assert main(["compare", ra, rb, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "right: 6 gained, 0 lost (sign test p = 0.031)" in text
    assert json.loads(out.read_text())["moves"] == {"refused->right": 6}
    assert main(["compare", ra, str(tmp_path / "none.json")]) == 2
    assert "none.scenes.json" in capsys.readouterr().err
