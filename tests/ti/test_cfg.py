"""mmatch.drivers.ti.cfg: parse, validate, derive (ti_formats.md 1c)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from mmatch.drivers.ti.cfg import ChirpParams, RadarCfg, load_cfg, parse_cfg, vehicle_warnings
from mmatch.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]

# davidmhunt dmh_1443config.cfg style (SDK 2.x xWR14xx), the reference's worked example.
DMH_1443 = """\
% xWR14xx example
sensorStop
flushCfg
dfeDataOutputMode 1
channelCfg 15 5 0
adcCfg 2 1
adcbufCfg 0 1 0 1
profileCfg 0 77 429 7 57.14 0 0 70 1 240 4884 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 4
frameCfg 0 1 16 0 100 1 0
guiMonitor 1 0 0 0 0 0
cfarCfg 0 1 4 4 0 1 0 15
sensorStart
"""


def test_reference_example_numbers():
    cfg = parse_cfg(DMH_1443, "dmh.cfg")
    c = cfg.chirp
    assert isinstance(cfg, RadarCfg) and isinstance(c, ChirpParams)
    assert c.range_resolution_m == pytest.approx(0.04361, abs=1e-5)
    assert c.range_idx_to_m == pytest.approx(0.04088, abs=1e-5)
    assert c.doppler_resolution_mps == pytest.approx(0.1252, abs=1e-4)
    assert c.max_velocity_mps == pytest.approx(1.0018, abs=1e-4)
    assert c.max_range_m == pytest.approx(0.9 * 4884e3 * 3e8 / (2 * 70e12))
    assert (c.num_tx, c.num_rx, c.tx_order) == (2, 4, (0, 2))
    assert (c.num_loops, c.chirps_per_frame, c.num_doppler_bins, c.num_range_bins) == (16, 32, 16, 256)
    assert c.frame_period_ms == 100.0
    assert (c.rx_mask, c.tx_mask) == (15, 5)
    assert c.chirp_time_us == pytest.approx(486.14)


def test_commands_skip_comments_and_keep_line_numbers():
    cfg = parse_cfg(DMH_1443)
    assert cfg.commands[0] == (2, "sensorStop", ())
    assert cfg.commands[-1] == (14, "sensorStart", ())
    assert all(not cmd.startswith("%") for _, cmd, _ in cfg.commands)
    assert cfg.lines()[6] == "profileCfg 0 77 429 7 57.14 0 0 70 1 240 4884 0 0 30"
    assert len(cfg.commands) == 13


def test_slow_profile_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="mmatch.drivers.ti.cfg"):
        cfg = parse_cfg(DMH_1443, "dmh.cfg")
    assert any("max velocity 1.00 m/s" in w for w in cfg.warnings)
    assert "max velocity" in caplog.text and "dmh.cfg" in caplog.text


@pytest.mark.parametrize("path", sorted((REPO / "cfg" / "radar").glob("*.cfg")), ids=lambda p: p.name)
def test_shipped_vehicle_cfgs(path):
    cfg = load_cfg(path)
    c = cfg.chirp
    assert c.max_velocity_mps > 28.0
    assert c.max_range_m >= 100.0
    assert cfg.warnings == ()
    assert vehicle_warnings(c) == []
    assert cfg.commands[-1][1] == "sensorStart"


def test_shipped_cfg_count():
    assert len(list((REPO / "cfg" / "radar").glob("*.cfg"))) >= 2


def _replace(text: str, prefix: str, new: str) -> str:
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith(prefix):
            lines[i] = new
            return "\n".join(lines) + "\n"
    raise AssertionError(prefix)


@pytest.mark.parametrize("prefix, new, line, words", [
    ("guiMonitor", "guiMonitr 1 0 0 0 0 0", 12, "unknown command 'guiMonitr'"),
    ("chirpCfg 0", "chirpCfg 0 0 0 0 0 0 1", 9, "expected 8 arguments, got 7"),
    ("profileCfg", "profileCfg 0 77 429 7 57.14 0 0 70 1 240 4884 0 0", 8, "expected 14 arguments"),
    ("profileCfg", "profileCfg 0 77 429 7 57.14 0 0 seventy 1 240 4884 0 0 30", 8, "not a number"),
    ("profileCfg", "profileCfg 0 90 429 7 57.14 0 0 70 1 240 4884 0 0 30", 8, "outside"),
    ("profileCfg", "profileCfg 0 77 429 7 40 0 0 70 1 240 4884 0 0 30", 8, "after the ramp ends"),
    ("profileCfg", "profileCfg 0 77 429 7 57.14 0 0 -70 1 240 4884 0 0 30", 8, "must be > 0"),
    ("profileCfg", "profileCfg 0 80 429 7 57.14 0 0 70 1 240 4884 0 0 30", 8, "above the 76-81 GHz band"),
    ("frameCfg", "frameCfg 0 1 16 0 10 1 0", 11, "longer than the frame period"),
    ("frameCfg", "frameCfg 0 2 16 0 100 1 0", 11, "chirp index 2 has no chirpCfg"),
    ("chirpCfg 1", "chirpCfg 1 1 0 0 0 0 0 2", 10, "not a non-empty subset"),
    ("chirpCfg 1", "chirpCfg 1 1 3 0 0 0 0 4", 10, "profileId 3 has no profileCfg"),
    ("channelCfg", "channelCfg 0 5 0", 5, "rxChannelEn"),
    ("frameCfg", "frameCfg 0 1 1.5 0 100 1 0", 11, "must be an integer"),
])
def test_refused_naming_the_line(prefix, new, line, words):
    with pytest.raises(ConfigError) as exc:
        parse_cfg(_replace(DMH_1443, prefix, new), "x.cfg")
    msg = str(exc.value)
    assert msg.startswith(f"x.cfg:{line}:"), msg
    assert words in msg


def test_missing_frame_cfg_refused():
    text = "\n".join(l for l in DMH_1443.splitlines() if not l.startswith("frameCfg"))
    with pytest.raises(ConfigError, match="missing frameCfg"):
        parse_cfg(text, "x.cfg")


def test_comp_range_bias_pairs():
    parse_cfg(DMH_1443 + "compRangeBiasAndRxChanPhase 0.0 1 0 1 0 1 0 1 0\n")
    with pytest.raises(ConfigError, match=r"x.cfg:15: .*pairs"):
        parse_cfg(DMH_1443 + "compRangeBiasAndRxChanPhase 0.0 1 0 1\n", "x.cfg")


def test_advanced_frame_uses_subframe0():
    text = DMH_1443.replace("dfeDataOutputMode 1", "dfeDataOutputMode 3").replace(
        "frameCfg 0 1 16 0 100 1 0",
        "advFrameCfg 2 0 0 1 0\nsubFrameCfg 0 0 0 2 32 200 0 1 1 200\nsubFrameCfg 1 0 0 2 16 100 0 1 1 100")
    c = parse_cfg(text).chirp
    assert (c.num_loops, c.chirps_per_frame, c.frame_period_ms) == (32, 64, 200.0)


def test_load_cfg_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_cfg(tmp_path / "nope.cfg")


def test_load_cfg_names_path(tmp_path):
    p = tmp_path / "bad.cfg"
    p.write_text("sensorStop\nfoo 1 2\n")
    with pytest.raises(ConfigError, match=r"bad.cfg:2: unknown command 'foo'"):
        load_cfg(p)
