"""The vehicle config: defaults, round trip, and refusal of bad input naming the key."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from mmatch.edge import config
from mmatch.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def test_defaults_round_trip_through_toml():
    cfg = config.from_dict({"vehicle": {"id": "ego1", "role": "ego"}, "zenoh": {"listen": ["tcp/127.0.0.1:7447"]}})
    assert cfg.vehicle.id == "ego1" and cfg.is_ego and not cfg.is_cav
    assert cfg.radar.baudrate == 921600
    again = config.from_dict(tomllib.loads(config.to_toml(cfg)))
    assert again == cfg


def test_int_is_accepted_for_float():
    cfg = config.from_dict({"sim": {"rate_hz": 10}})
    assert cfg.sim.rate_hz == 10.0 and isinstance(cfg.sim.rate_hz, float)


@pytest.mark.parametrize("data, key", [
    ({"radar": {"prot": "/dev/ttyUSB0"}}, "radar.prot"),
    ({"nonsense": {}}, "nonsense"),
    ({"radar": {"baudrate": "921600"}}, "radar.baudrate"),
    ({"radar": {"baudrate": 9.5}}, "radar.baudrate"),
    ({"log": {"raw": 1}}, "log.raw"),
    ({"sim": {"rate_hz": True}}, "sim.rate_hz"),
    ({"radar": {"baudrate": 0}}, "radar.baudrate"),
    ({"sim": {"rate_hz": 0.0}}, "sim.rate_hz"),
    ({"sim": {"rate_hz": float("nan")}}, "sim.rate_hz"),
    ({"vehicle": {"role": "truck"}}, "vehicle.role"),
    ({"vehicle": {"id": "a/b"}}, "vehicle.id"),
    ({"zenoh": {"listen": "tcp/127.0.0.1:1"}}, "zenoh.listen"),
    ({"zenoh": {"listen": [1]}}, "zenoh.listen[0]"),
    ({"zenoh": {"connect": ["localhost"]}}, "zenoh.connect[0]"),
    ({"zenoh": {"mode": "client"}}, "zenoh.connect"),
    ({"radar": {"source": "uart"}}, "radar.port"),
    ({"radar": {"source": "replay"}}, "radar.path"),
    ({"log": {"floor_mb": 10, "raw_floor_mb": 5}}, "log.floor_mb"),
    ({"sim": {"rate_hz": 20, "phase_s": 0.06}}, "sim.phase_s"),
    ({"ego": {"pair_tolerance_s": -0.1}}, "ego.pair_tolerance_s"),
    ({"radar": 3}, "radar"),
])
def test_bad_values_are_refused_naming_the_key(data, key):
    with pytest.raises(ConfigError) as err:
        config.from_dict(data)
    assert f"{key}:" in str(err.value)


def test_load_names_file_and_key(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text('[vehicle]\nid = "x"\n[radar]\nbaud = 5\n')
    with pytest.raises(ConfigError, match=r"v\.toml: radar\.baud: unknown key"):
        config.load(p)
    p.write_text("[vehicle\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        config.load(p)
    with pytest.raises(ConfigError, match="no such file"):
        config.load(tmp_path / "missing.toml")


def test_overrides_merge_on_top(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text('[vehicle]\nid = "x"\nrole = "cav"\n[sim]\nseed = 4\n')
    cfg = config.load(p, overrides={"sim": {"rate_hz": 5.0}, "vehicle": {"role": "ego"}})
    assert (cfg.vehicle.id, cfg.vehicle.role, cfg.sim.seed, cfg.sim.rate_hz) == ("x", "ego", 4, 5.0)


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "cfg").glob("vehicle*.toml")))
def test_shipped_configs_load(name):
    cfg = config.load(REPO / "cfg" / name)
    assert cfg.vehicle.id


def test_effective_config_is_logged(caplog):
    cfg = config.from_dict({"vehicle": {"id": "ego7"}})
    with caplog.at_level("INFO", logger="mmatch.edge.config"):
        config.log_effective(cfg)
    assert any("id='ego7'" in r.getMessage() for r in caplog.records)


def test_set_overrides_parse_toml_values():
    assert config.parse_overrides(["sim.rate_hz=10", "radar.port=/dev/ttyUSB1", 'vehicle.id="a"',
                                   "zenoh.listen=[\"tcp/127.0.0.1:1\"]"]) == {
        "sim": {"rate_hz": 10}, "radar": {"port": "/dev/ttyUSB1"}, "vehicle": {"id": "a"},
        "zenoh": {"listen": ["tcp/127.0.0.1:1"]}}
    with pytest.raises(ConfigError, match="SECTION.KEY=VALUE"):
        config.parse_overrides(["rate=1"])
