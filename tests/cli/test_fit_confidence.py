"""`mmatch fit-confidence`: a model of today's evidence from labelled folders, even when the
packaged model is stale (its features from before an evidence change)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mmatch.edge.cli import main
from mmatch.ego import confidence
from mmatch.ego.confidence import FEATURES, ProbabilityModel
from mmatch.errors import ConfigError
from mmatch.sim.generate import generate


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit")
    generate(out, 16, seed=31, mode="hard", jobs=1, physics="wide")
    return out


@pytest.fixture
def stale_package(tmp_path, monkeypatch):
    """The packaged model replaced by one whose features are one short of today's."""
    good = json.loads(confidence.MODEL_PATH.read_text())
    for k in ("features", "mean", "scale", "coef"):
        good[k] = good[k][:-1]
    stale = tmp_path / "stale.json"
    stale.write_text(json.dumps(good))
    confidence.load_model.cache_clear()
    monkeypatch.setattr(confidence, "MODEL_PATH", stale)
    yield stale
    confidence.load_model.cache_clear()


def _check(path) -> ProbabilityModel:
    model = ProbabilityModel.from_json(path.read_text(), str(path))
    assert model.features == FEATURES and 0.0 <= model.threshold <= 1.0 and model.inflation > 0
    assert model.meta["scenes"] == 16 and model.meta["candidates"] > 16
    return model


def test_fits_a_model_of_todays_evidence(folder, tmp_path, capsys):
    out = tmp_path / "model.json"
    assert main(["fit-confidence", str(folder), "--matchers", "consensus", "--out", str(out)]) == 0
    model = _check(out)
    assert "threshold" in capsys.readouterr().out
    sub = model.without_heading                 # the second model, for frames without a heading prior
    assert sub is not None and sub.meta["heading_prior"] is False and sub.meta["scenes"] == 16
    assert model.for_heading(False) is sub and model.for_heading(True) is model
    again = ProbabilityModel.from_json(model.to_json())
    assert again.without_heading is not None and np.allclose(again.without_heading.coef, sub.coef)
    # boosted trees beside the first regression, fit on the default matcher's candidates
    assert model.trees is not None and model.meta["trees"]["matcher"] == "consensus-rmnet"
    assert sub.trees is not None and sub.chooser is not None and sub.meta["trees"]["heading_prior"] is False
    x = np.array([model.mean, model.mean + model.scale])
    np.testing.assert_allclose(again.rate(x)[0], model.rate(x)[0])
    np.testing.assert_allclose(model.rate(x)[0], 0.5 * (model.probability(x) + model.trees.probability(
        (x - model.mean) / model.scale)))


def test_second_model_fits_on_its_own_folders(folder, tmp_path_factory, tmp_path):
    """--without-heading-folders: the model for frame pairs without a heading prior learns from
    other folders than the first (all of its stages: regression, calibration), and a folder that
    is not one is refused before any fitting."""
    other = tmp_path_factory.mktemp("fit_second")
    generate(other, 16, seed=32, mode="hard", jobs=1, physics="wide")
    out = tmp_path / "model.json"
    assert main(["fit-confidence", str(folder), "--without-heading-folders", str(other), "--matchers",
                 "consensus", "--no-trees", "--out", str(out)]) == 0
    model = ProbabilityModel.from_json(out.read_text())
    assert model.meta["scenes"] == 16 and model.meta["folders"] == [str(folder)]
    sub = model.without_heading
    assert sub.meta["scenes"] == 16 and sub.meta["folders"] == [str(other)] and sub.meta["heading_prior"] is False
    assert sub.meta["calibration_choice"].endswith(f"chosen estimates of {other}")
    assert model.meta["calibration_choice"].endswith(f"chosen estimates of {folder}")
    assert main(["fit-confidence", str(folder), "--without-heading-folders", str(tmp_path / "missing"),
                 "--out", str(out)]) == 2


def _packaged_copy(tmp_path: Path) -> tuple[Path, ProbabilityModel]:
    """A copy of the packaged model file for a `--*-only` refit to rewrite, and what it holds."""
    out = tmp_path / "model.json"
    out.write_text(confidence.MODEL_PATH.read_text())
    return out, ProbabilityModel.from_json(out.read_text())


def test_trees_only_keeps_the_regressions_and_no_trees_leaves_them_out(folder, tmp_path):
    out, kept = _packaged_copy(tmp_path)
    assert main(["fit-confidence", str(folder), "--trees-only", "--out", str(out)]) == 0
    model = ProbabilityModel.from_json(out.read_text())
    np.testing.assert_array_equal(model.coef, kept.coef)
    assert model.threshold == kept.threshold and model.inflation == kept.inflation
    np.testing.assert_array_equal(model.without_heading.coef, kept.without_heading.coef)
    assert model.trees is not None and model.chooser is not None and model.meta["trees"]["candidates"] > 16
    assert model.meta["trees"]["folders"] == [str(folder)]
    assert model.without_heading.trees is not None                 # both models get theirs
    assert model.without_heading.meta["trees"]["heading_prior"] is False
    first_only = tmp_path / "first.json"
    first_only.write_text(confidence.MODEL_PATH.read_text())
    assert main(["fit-confidence", str(folder), "--trees-only", "--no-without-heading", "--out", str(first_only)]) == 0
    m1 = ProbabilityModel.from_json(first_only.read_text())
    assert m1.without_heading.trees is not None               # the packaged second model's, kept
    assert m1.without_heading.meta["trees"] == kept.without_heading.meta["trees"]
    plain = tmp_path / "plain.json"
    assert main(["fit-confidence", str(folder), "--matchers", "consensus", "--no-without-heading", "--no-trees",
                 "--out", str(plain)]) == 0
    plain_model = ProbabilityModel.from_json(plain.read_text())
    assert plain_model.trees is None and plain_model.chooser is None
    assert main(["fit-confidence", str(folder), "--trees-only", "--out", str(tmp_path / "none.json")]) == 2


def test_a_broken_tree_block_is_refused_naming_the_file(tmp_path):
    d = json.loads(confidence.MODEL_PATH.read_text())
    assert "trees" in d                                       # the packaged model has them
    for change in ({"left": [[5] * len(d["trees"]["left"][0])] * len(d["trees"]["left"])},   # children out of the tree
                   {"feature": [[99] * len(d["trees"]["feature"][0])] * len(d["trees"]["feature"])},
                   {"value": "x"}):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(dict(d, trees=dict(d["trees"], **change))))
        confidence.load_model.cache_clear()
        with pytest.raises(ConfigError, match=f"{bad}: trees"):
            confidence.load_model(str(bad))
    short = dict(d, chooser=dict(d["chooser"], feature=[[len(FEATURES) * 2 + 4] * len(d["chooser"]["feature"][0])]
                                 * len(d["chooser"]["feature"])))     # reads past its 2 F + 4 features
    bad.write_text(json.dumps(short))
    confidence.load_model.cache_clear()
    with pytest.raises(ConfigError, match=f"{bad}: chooser: trees"):
        confidence.load_model(str(bad))


def test_the_second_model_can_be_left_out(folder, tmp_path):
    out = tmp_path / "model.json"
    assert main(["fit-confidence", str(folder), "--matchers", "consensus", "--no-without-heading",
                 "--out", str(out)]) == 0
    model = _check(out)
    assert model.without_heading is None and model.for_heading(False) is model


def test_a_broken_second_model_is_refused_naming_the_file(tmp_path):
    d = json.loads(confidence.MODEL_PATH.read_text())
    d["without_heading"] = dict(d["without_heading"], coef=d["without_heading"]["coef"][:-1])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    with pytest.raises(ConfigError, match=f"{bad}: without_heading"):
        confidence.load_model(str(bad))


def test_a_stale_packaged_model_does_not_stop_the_fit(folder, tmp_path, stale_package, capsys):
    out = tmp_path / "model.json"
    assert main(["fit-confidence", str(folder), "--matchers", "consensus", "--out", str(out)]) == 0
    assert "evaluating without it" in capsys.readouterr().err
    model = _check(out)
    assert np.any(model.coef != 0)
    assert stale_package.read_text() != out.read_text()      # --out, not the package, was written


def test_the_fit_does_not_depend_on_the_installed_model(folder, tmp_path, monkeypatch):
    """The evaluation behind a fit runs under a neutral model: what is installed (here the packaged
    model, then one whose features are stale) does not change the fitted model."""
    args = ["fit-confidence", str(folder), "--matchers", "consensus", "--no-without-heading",
            "--no-trees"]
    under_packaged, under_stale = tmp_path / "packaged.json", tmp_path / "stale.json"
    confidence.load_model.cache_clear()
    assert confidence.load_model() is not None
    assert main([*args, "--out", str(under_packaged)]) == 0
    good = json.loads(confidence.MODEL_PATH.read_text())
    for k in ("features", "mean", "scale", "coef"):
        good[k] = good[k][:-1]
    (tmp_path / "installed.json").write_text(json.dumps(good))
    confidence.load_model.cache_clear()
    monkeypatch.setattr(confidence, "MODEL_PATH", tmp_path / "installed.json")
    assert main([*args, "--out", str(under_stale)]) == 0
    confidence.load_model.cache_clear()
    a, b = (ProbabilityModel.from_json(p.read_text()) for p in (under_packaged, under_stale))
    np.testing.assert_array_equal(a.coef, b.coef)
    assert a.threshold == b.threshold and a.inflation == b.inflation


def test_threshold_only_keeps_the_model_and_chooses_its_threshold_on_tuning_families(folder, tmp_path, capsys):
    out, kept = _packaged_copy(tmp_path)
    assert main(["fit-confidence", "--threshold-only", "--threshold-on", f"{folder},{folder}",
                 "--threshold-on", str(folder), "--threshold-max-gross", "0.2", "--out", str(out)]) == 0
    model = ProbabilityModel.from_json(out.read_text())
    np.testing.assert_array_equal(model.coef, kept.coef)
    assert model.inflation == kept.inflation and model.without_heading.threshold == kept.without_heading.threshold
    assert 0.0 < model.threshold <= 1.0 and round(model.threshold * 100) == pytest.approx(model.threshold * 100)
    assert model.meta["threshold_choice"].startswith(f"{model.threshold:.2f}: ")
    assert capsys.readouterr().out.count(f"threshold {model.threshold:.2f} on ") == 2
    for bad in (["--threshold-only"], [], ["--threshold-only", "--threshold-on", str(folder), "--threshold-max-gross", "1.5"],
                ["--threshold-only", "--threshold-on", str(tmp_path / "missing")]):
        assert main(["fit-confidence", *bad, "--out", str(out)]) == 2, bad


def test_inflation_only_keeps_the_model_and_refits_its_covariance_inflation(folder, tmp_path, capsys):
    """The factor that makes the 95 % ellipse of the published estimates hold the truth for 95 %
    of the successful ones: refit under the refit inflation, it stays (1 within the quantile's
    step), and nothing else of the model moves."""
    out, kept = _packaged_copy(tmp_path)
    assert main(["fit-confidence", str(folder), "--inflation-only", "--out", str(out)]) == 0
    model = ProbabilityModel.from_json(out.read_text())
    np.testing.assert_array_equal(model.coef, kept.coef)
    assert model.threshold == kept.threshold and model.without_heading.threshold == kept.without_heading.threshold
    for mine, before in ((model, kept), (model.without_heading, kept.without_heading)):
        assert mine.inflation > 0 and mine.inflation != before.inflation
        assert mine.meta["inflation_choice"].startswith(f"{mine.inflation:.3f}: refit alone")
    printed = capsys.readouterr().out
    assert f"-> {model.inflation:.3f}" in printed and f"prior {kept.without_heading.inflation:.3f} -> " in printed
    confidence.load_model.cache_clear()
    assert main(["fit-confidence", str(folder), "--inflation-only", "--out", str(out)]) == 0
    again = ProbabilityModel.from_json(out.read_text())
    assert again.inflation == pytest.approx(model.inflation, rel=0.15)
    confidence.load_model.cache_clear()
    assert main(["fit-confidence", str(folder), "--inflation-only", "--no-without-heading", "--out", str(out)]) == 0
    assert ProbabilityModel.from_json(out.read_text()).without_heading.inflation == again.without_heading.inflation
    for bad in (["--inflation-only"], [str(folder), "--inflation-only", "--threshold-only"],
                [str(tmp_path / "missing"), "--inflation-only"]):
        assert main(["fit-confidence", *bad, "--out", str(out)]) == 2, bad


def test_calibration_only_keeps_the_model_and_fits_the_published_map(folder, tmp_path, capsys):
    """The map from the model's probability to the published confidence, fit on the chosen
    estimates (both models): nothing else of the model moves, and it says what it did."""
    out, kept = _packaged_copy(tmp_path)
    assert main(["fit-confidence", str(folder), "--calibration-only", "--out", str(out)]) == 0
    model = ProbabilityModel.from_json(out.read_text())
    np.testing.assert_array_equal(model.coef, kept.coef)
    assert (model.threshold, model.inflation) == (kept.threshold, kept.inflation)
    for mine in (model, model.without_heading):
        a, b = mine.calibration
        assert a > 0 and np.isfinite(b) and mine.meta["calibration_choice"].startswith(f"a {a:.4f}, b {b:.4f}: ")
    printed = capsys.readouterr().out
    assert "expected calibration error" in printed and printed.count("16 chosen estimates") == 2
    for bad in (["--calibration-only"], [str(folder), "--calibration-only", "--inflation-only"]):
        assert main(["fit-confidence", *bad, "--out", str(out)]) == 2, bad
