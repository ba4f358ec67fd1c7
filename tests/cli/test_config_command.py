"""`mmatch config`: examples and shipped files from the package, checks, generated docs."""

from __future__ import annotations

from pathlib import Path

import pytest

from mmatch.edge import config, docgen
from mmatch.edge.cli import main

REPO = Path(__file__).resolve().parents[2]


def test_examples_are_the_shipped_configs_and_load(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["config", "--example", "ego"]) == 0
    assert main(["config", "--example", "cav"]) == 0
    out = capsys.readouterr().out
    assert "wrote vehicle-ego-sim.toml" in out and "mmatch run -c vehicle-cav-sim.toml" in out
    for name in ("vehicle-ego-sim.toml", "vehicle-cav-sim.toml"):
        assert (tmp_path / name).read_text() == (REPO / "cfg" / name).read_text()
    ego = config.load(tmp_path / "vehicle-ego-sim.toml")
    cav = config.load(tmp_path / "vehicle-cav-sim.toml")
    assert ego.is_ego and cav.is_cav and cav.vehicle.id in ego.ego.cavs
    assert ego.zenoh.listen == cav.zenoh.connect == ["tcp/127.0.0.1:7460"]  # not zenohd's 7447
    assert main(["config", "--example", "cav"]) == 2                         # no silent overwrite
    assert "exists (--force overwrites it)" in capsys.readouterr().err
    assert main(["config", "--example", "cav", "--force", "--out", "mine.toml"]) == 0
    assert config.load(tmp_path / "mine.toml") == cav


def test_shipped_files_list_and_get(tmp_path, capsys):
    assert main(["config", "--list"]) == 0
    listed = capsys.readouterr().out.split()
    for name in ("cfg/radar/xwr68xx_vehicle_100m.cfg", "cfg/zenoh/router.json5", "systemd/mmatch-edge.service",
                 "cfg/vehicle.toml"):
        assert name in listed
    assert main(["config", "--get", "systemd/mmatch-edge.service", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "mmatch-edge.service").read_text() == (REPO / "systemd/mmatch-edge.service").read_text()
    assert main(["config", "--get", "radar/nope.cfg"]) == 2
    assert "not a shipped file" in capsys.readouterr().err


def test_check_names_the_bad_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[radar]\nbaudrate = "fast"\n')
    assert main(["config", "--check", str(bad)]) == 2
    assert "radar.baudrate: expected an integer" in capsys.readouterr().err
    assert main(["config", "--check", str(REPO / "cfg/vehicle.toml"), "--set", "vehicle.id=\"cav9\""]) == 0
    assert 'id = "cav9"' in capsys.readouterr().out


@pytest.mark.parametrize("name", sorted(docgen.PAGES))
def test_committed_reference_pages_are_current(name):
    committed = (REPO / "docs" / name).read_text()
    assert committed == docgen.PAGES[name](), f"docs/{name} is out of date: run `mmatch config --docs docs`"


def test_config_reference_covers_every_key():
    text = docgen.config_reference()
    for section, values in config.to_dict(config.VehicleConfig()).items():
        assert f"## [{section}]" in text
        for key in values:
            row = next(line for line in text.splitlines() if line.startswith(f"| `{key}` |"))
            assert row.rstrip().endswith("|") and not row.endswith("|  |"), f"{section}.{key} has no meaning"


def test_demo_without_the_plots_extra_still_works(tmp_path, monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "matplotlib" else real(name, *a))
    assert main(["demo", "--out", str(tmp_path / "d"), "--n", "2", "--jobs", "1"]) == 0
    assert "picture skipped: it needs matplotlib, pip install 'mmatch[plots]'" in capsys.readouterr().out
    assert (tmp_path / "d/eval.json").exists() and not list((tmp_path / "d").glob("bev*"))
