"""`mmatch ablation`: every matcher on the same scenes in one run; `mmatch bench --only rmnet`."""

from __future__ import annotations

import json

from mmatch.ablation import ABLATION
from mmatch.edge.cli import main
from mmatch.sim.generate import generate


def test_ablation_runs_every_matcher_on_the_same_scenes(tmp_path, capsys):
    generate(tmp_path / "scenes", 4, seed=61, mode="hard")
    out = tmp_path / "ablation.json"
    assert main(["ablation", str(tmp_path / "scenes"), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| RM-net + verification (`rmnet`)" in text and "| geometry only (`geometry`)" in text
    rep = json.loads(out.read_text())
    assert list(rep) == list(ABLATION)
    assert {r["scenes"] for r in rep.values()} == {4}
    assert len({r["config"]["descriptor_scale"] for r in rep.values()}) == 1
    # the RM-net-alone and descriptor-only matchers give no transform: the aligner works from their pairs
    assert all(0 <= r["pair_precision"] <= 1 for r in rep.values())


def test_bench_suite(tmp_path, capsys):
    assert main(["bench", "--only", "rmnet", "--quick", "--out", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "bench.json").read_text())["rmnet"]
    assert rep["inference_ms_20x20"] > 0 and rep["inference_ms_40x40"] > 0
    assert rep["dense_vehicles_per_view_median"] >= 30
    assert 0 <= rep["dense_success"] <= 1
