"""`mmatch report` gives the numbers `mmatch eval` gives, for every method, and its figures."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from mmatch.edge.cli import main
from mmatch.errors import ConfigError
from mmatch.report.methods import resolve
from mmatch.report.tables import THRESHOLDS, _bins, f1, success_at

TIMING_KEYS = {"latency_ms"}


def _same(a, b, path="") -> None:
    """Exact equality of two JSON values (NaN equals NaN), naming the first difference."""
    if isinstance(a, dict):
        assert set(a) == set(b), f"{path}: keys {sorted(set(a) ^ set(b))}"
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), f"{path}: length {len(a)} != {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        assert math.isnan(b), f"{path}: NaN != {b}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


@pytest.fixture(scope="module")
def report_dir(small_hard, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert main(["report", str(small_hard), "--out", str(out), "--jobs", "1"]) == 0
    return out


def test_every_number_equals_mmatch_eval(report_dir, small_hard, tmp_path):
    rep = json.loads((report_dir / "report.json").read_text())
    keys = [m["key"] for m in rep["methods"]]
    assert {"mmatch", "true-pairs", "yardstick", "paper", "icp-all", "icp-bg", "icp-veh", "icp-pair",
            "gicp"} <= set(keys)
    assert rep["files"] == 8 and rep["reference"] == "mmatch"
    for m in rep["methods"]:
        out = tmp_path / f"{m['key']}.json"
        assert main(["eval", str(small_hard), "--matcher", m["matcher"], "--aligner", m["aligner"],
                     "--json", str(out)]) == 0
        ev = json.loads(out.read_text())
        mine = {k: v for k, v in m["eval"].items() if k not in TIMING_KEYS}
        _same(mine, {k: v for k, v in ev.items() if k not in TIMING_KEYS}, m["key"])
        scenes = json.loads(out.with_suffix(".scenes.json").read_text())
        ours = json.loads((report_dir / "scenes" / f"{m['key']}.scenes.json").read_text())
        strip = lambda rows: [{k: v for k, v in r.items() if k != "stages_ms"} for r in rows]  # noqa: E731
        _same(strip(ours), strip(scenes), m["key"] + " scenes")
        for name, a, b in THRESHOLDS:
            assert m["derived"]["success"][name] == success_at(scenes, a, b)
        assert m["derived"]["success"]["5deg_2m"] == ev["success_rate"]
        assert m["derived"]["pair_f1"] == f1(ev["pair_precision"], ev["pair_recall"])
    summary = (report_dir / "summary.md").read_text()
    mm = next(m for m in rep["methods"] if m["key"] == "mmatch")
    assert f"| MMatch | consensus-rmnet + constrained | {mm['derived']['success']['5deg_2m']:.3f} |" in summary
    cfg = json.loads((report_dir / "config.json").read_text())
    assert [c["key"] for c in cfg["methods"]] == keys
    assert cfg["methods"][0]["aligner_config"]["refine"]["iterations"] > 0


def test_eval_options_pass_through(small_hard, tmp_path):
    out = tmp_path / "rep"
    flags = ["--confidence-threshold", "0", "--descriptor-scale", "auto"]
    assert main(["report", str(small_hard), "--out", str(out), "--methods", "mmatch", "--jobs", "1",
                 "--no-plots", *flags]) == 0
    mine = json.loads((out / "report.json").read_text())["methods"][0]["eval"]
    assert main(["eval", str(small_hard), "--json", str(tmp_path / "e.json"), *flags]) == 0
    ev = json.loads((tmp_path / "e.json").read_text())
    assert ev["config"]["confidence_threshold"] == 0 and ev["coverage"] == 1.0
    _same({k: v for k, v in mine.items() if k not in TIMING_KEYS}, {k: v for k, v in ev.items() if k not in TIMING_KEYS})


def test_breakdowns_cover_every_scene(report_dir):
    rep = json.loads((report_dir / "report.json").read_text())
    for m in rep["methods"]:
        for key in ("co_visible", "vehicles_per_view", "road", "relation"):
            rows = m["breakdowns"][key]
            assert sum(r["scenes"] for r in rows) == m["eval"]["scenes"]
            assert all(0.0 <= r["success_rate"] <= 1.0 for r in rows)


def test_figures_are_written_as_png_and_svg(report_dir):
    rep = json.loads((report_dir / "report.json").read_text())
    for name in ("cdf", "by_co_visible", "by_vehicles_per_view", "by_road_direction", "latency", "payload"):
        assert (report_dir / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert b"<svg" in (report_dir / f"{name}.svg").read_bytes()[:400]
        assert f"{name}.png" in rep["figures"]
    bev = sorted(p.name for p in report_dir.glob("bev_*.svg"))
    assert bev, "no bird's-eye picture"
    text = (report_dir / bev[0]).read_text()
    assert "RTE" in text and "RRE" in text and "x (m)" in text


def test_missing_open3d_is_skipped_with_the_install_line(small_hard, tmp_path):
    code = ("import sys; sys.modules['open3d'] = None; from mmatch.edge.cli import main; "
            f"sys.exit(main(['report', {str(small_hard)!r}, '--out', {str(tmp_path)!r}, '--methods', "
            "'yardstick,o3d-icp', '--jobs', '1', '--no-plots']))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "skipped o3d-icp" in run.stderr and "pip install 'mmatch[baselines]'" in run.stderr
    rep = json.loads((tmp_path / "report.json").read_text())
    assert [m["key"] for m in rep["methods"]] == ["yardstick"]
    assert rep["skipped"][0]["key"] == "o3d-icp"
    assert "skipped Open3D ICP" in (tmp_path / "summary.md").read_text()
    assert not list(tmp_path.glob("*.png"))


def test_progress_lines_off_a_terminal(small_hard, tmp_path, capsys):
    assert main(["report", str(small_hard), "--out", str(tmp_path), "--methods", "yardstick", "--jobs", "1",
                 "--no-plots"]) == 0
    assert "report: 8/8 done in" in capsys.readouterr().err


def test_methods_are_checked_by_name():
    assert [m.key for m in resolve(["mmatch", "oracle+icp-pair"])] == ["mmatch", "oracle+icp-pair"]
    with pytest.raises(ConfigError, match="unknown method 'nope'"):
        resolve(["nope"])
    with pytest.raises(ConfigError, match="unknown aligner 'twirl'"):
        resolve(["oracle+twirl"])
    with pytest.raises(ConfigError, match="given twice"):
        resolve(["mmatch", "mmatch"])


def test_numeric_bins_merge_thin_tails():
    labels = _bins([2] * 10 + [3] * 6 + [4] * 3 + [5] * 1 + [6] * 1, numeric=True)
    assert labels == {2: "2", 3: "3", 4: ">=4", 5: ">=4", 6: ">=4"}
    labels = _bins([1] * 2 + [2] * 4 + [3] * 9, numeric=True)
    assert labels == {1: "<=2", 2: "<=2", 3: "3"}


def test_risk_coverage_is_drawn_only_when_finite(tmp_path):
    from mmatch.report.plots import risk_coverage_figure
    curve = [{"coverage": c, "gross_rate": 0.2 * c, "success_rate": 1 - 0.3 * c} for c in np.linspace(0.5, 1, 6)]
    rep = {"methods": [{"key": "a", "label": "A", "group": "ours", "eval": {"risk_coverage": curve}},
                       {"key": "b", "label": "B", "group": "ours",
                        "eval": {"risk_coverage": [{"coverage": float("nan"), "gross_rate": 0.1}]}}]}
    assert risk_coverage_figure(tmp_path, rep) == ["risk_coverage.png", "risk_coverage.svg"]
    rep["methods"] = rep["methods"][1:]
    assert risk_coverage_figure(tmp_path / "none", rep) == []
