"""DSP on synthesised raw ADC: accuracy, resolution, sign conventions, CFAR variants."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from mmatch.drivers.dca1000.dsp import DspConfig, RadarDsp, make_dsp
from mmatch.drivers.dca1000.layout import FrameGeometry, cube_to_raw, raw_to_cube
from mmatch.drivers.dca1000.synth import Target, synth_cube
from mmatch.drivers.ti.cfg import parse_cfg


def _match(points: np.ndarray, t: Target, chirp) -> tuple[float, float, float, float]:
    """(range error in bins, Doppler error in bins, azimuth error deg, elevation error deg)
    of the point nearest to target t in range-Doppler cells."""
    assert len(points), "no points at all"
    r = np.linalg.norm(points[:, :3], axis=1)
    dr = (r - t.range_m) / chirp.range_resolution_m
    dv = (points[:, 3] - t.velocity_mps) / chirp.doppler_resolution_mps
    i = int(np.argmin(np.hypot(dr, dv)))
    az = np.degrees(np.arctan2(points[i, 0], points[i, 1]))
    el = np.degrees(np.arcsin(points[i, 2] / r[i]))
    return abs(dr[i]), abs(dv[i]), abs(az - t.azimuth_deg), abs(el - t.elevation_deg)


TARGETS = [
    Target(8.0, 0.0, 0.0, 0.0, 0.0),
    Target(15.3, 18.5, 30.0, 0.0, 0.0),  # fast, receding, right
    Target(27.1, -19.2, -40.0, 8.0, 0.0),  # fast, approaching, left, up
    Target(44.4, 7.7, 55.0, -6.0, 0.0),
    Target(70.2, -3.3, -12.0, 0.0, 5.0),
    Target(33.3, 12.0, 10.0, 0.0, -5.0),
]


@pytest.mark.parametrize("cfar", ["ca", "os"])
def test_targets_recovered_within_one_bin_and_two_degrees(radar_cfg, cfar):
    geom, dsp = make_dsp(radar_cfg, cfar=cfar)
    for seed in (0, 1):
        pts = dsp.process(
            synth_cube(radar_cfg.chirp, geom, TARGETS, rng=np.random.default_rng(seed))
        ).points
        assert len(pts) == len(TARGETS), pts
        for t in TARGETS:
            dr, dv, daz, del_ = _match(pts, t, radar_cfg.chirp)
            assert dr <= 1.0 and dv <= 1.0 and daz <= 2.0, (t, dr, dv, daz)
            assert del_ <= 2.0, (t, del_)


def test_signs_follow_design(dsp_setup):
    cfg, geom, dsp = dsp_setup
    cases = [
        (Target(20.0, 5.0, 35.0, 0.0), dict(x=+1, dop=+1)),
        (Target(20.0, -5.0, -35.0, 0.0), dict(x=-1, dop=-1)),
        (Target(20.0, 2.0, 0.0, 10.0), dict(z=+1)),
        (Target(20.0, 2.0, 0.0, -10.0), dict(z=-1)),
    ]
    for t, want in cases:
        pts = dsp.process(synth_cube(cfg.chirp, geom, [t])).points
        assert len(pts) == 1
        x, y, z, dop, snr = pts[0]
        assert y > 0
        if "x" in want:
            assert np.sign(x) == want["x"] and abs(x) > 5
        if "z" in want:
            assert np.sign(z) == want["z"] and abs(z) > 2
        if "dop" in want:
            assert np.sign(dop) == want["dop"]
        assert snr > 20


def test_virtual_channel_order_is_tx0_rx0_to_rx3_then_next_tx(dsp_setup):
    """With the true order the angles are right; any other channel order breaks them."""
    cfg, geom, dsp = dsp_setup
    t = Target(20.0, 0.0, 25.0, 0.0)
    cube = synth_cube(cfg.chirp, geom, [t])
    ok = _match(dsp.process(cube).points, t, cfg.chirp)
    assert ok[2] < 1.0 and ok[3] < 1.0
    for order in (
        [4, 5, 6, 7, 0, 1, 2, 3, 8, 9, 10, 11],  # TX1's block first
        [8, 9, 10, 11, 4, 5, 6, 7, 0, 1, 2, 3],  # TX2's block first
        [3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8],
    ):  # RX3..RX0 within each TX
        pts = dsp.process(cube[:, order, :]).points
        assert len(pts) == 0 or max(_match(pts, t, cfg.chirp)[2:]) > 5.0, order


def test_fast_target_needs_tdm_compensation(radar_cfg):
    t = Target(25.0, 0.9 * radar_cfg.chirp.max_velocity_mps, 30.0, 0.0)
    geom, dsp = make_dsp(radar_cfg)
    _, raw_dsp = make_dsp(radar_cfg, tdm_compensation=False)
    cube = synth_cube(radar_cfg.chirp, geom, [t])
    assert _match(dsp.process(cube).points, t, radar_cfg.chirp)[2] <= 2.0
    assert _match(raw_dsp.process(cube).points, t, radar_cfg.chirp)[2] > 5.0


@pytest.mark.parametrize("axis", ["range", "doppler"])
def test_two_targets_two_and_a_half_cells_apart_are_two_points(radar_cfg, dsp_setup, axis):
    cfg, geom, dsp = dsp_setup
    c = cfg.chirp
    for r0, v0 in ((20.0, 3.0), (31.17, -6.41)):
        if axis == "range":
            pair = [Target(r0, v0, 10.0), Target(r0 + 2.5 * c.range_resolution_m, v0, 10.0)]
        else:
            pair = [Target(r0, v0, 10.0), Target(r0, v0 + 2.5 * c.doppler_resolution_mps, 10.0)]
        pts = dsp.process(synth_cube(c, geom, pair)).points
        assert len(pts) == 2, pts
        for t in pair:
            dr, dv, daz, _ = _match(pts, t, c)
            assert dr <= 1.0 and dv <= 1.0 and daz <= 2.0


def test_os_and_caso_cfar_see_a_weak_target_beside_a_strong_one(radar_cfg):
    """Six range bins from a strong target, the weak one sits in the CA training window: the
    whole-ring mean (averageMode 0) masks it; the cfg's smaller-half mean (CASO) and OS do not."""
    c = radar_cfg.chirp
    strong = Target(30.0, 2.0, 0.0, 0.0, 25.0)
    weak = Target(30.0 + 6 * c.range_resolution_m, 2.0, 20.0, 0.0, -5.0)
    geom, ca = make_dsp(radar_cfg, cfar="ca", average="ca")
    _, caso = make_dsp(radar_cfg, cfar="ca")
    _, os_ = make_dsp(radar_cfg, cfar="os")
    assert caso.config.average == "caso"  # cfarCfg -1 0 2 ...: averageMode 2
    cube = synth_cube(c, geom, [strong, weak])
    pts_ca = ca.process(cube).points
    assert len(pts_ca) == 1 and _match(pts_ca, strong, c)[0] <= 1.0
    for dsp in (caso, os_):
        pts = dsp.process(cube).points
        assert len(pts) == 2 and _match(pts, weak, c)[0] <= 1.0


def test_clutter_removal_drops_static_targets(radar_cfg):
    geom, on = make_dsp(radar_cfg, clutter_removal=True)
    _, off = make_dsp(radar_cfg, clutter_removal=False)
    static, moving = Target(12.0, 0.0, -20.0), Target(25.0, 4.0, 15.0)
    cube = synth_cube(radar_cfg.chirp, geom, [static, moving])
    pts_off, pts_on = off.process(cube).points, on.process(cube).points
    assert len(pts_off) == 2
    assert len(pts_on) == 1 and _match(pts_on, moving, radar_cfg.chirp)[1] <= 1.0


def test_noise_alone_gives_almost_no_points(dsp_setup):
    cfg, geom, dsp = dsp_setup
    for seed in range(3):
        assert (
            len(
                dsp.process(synth_cube(cfg.chirp, geom, [], rng=np.random.default_rng(seed))).points
            )
            <= 2
        )


def test_config_from_cfg(radar_cfg):
    d = DspConfig.from_cfg(radar_cfg)
    assert d.guard == (4, 2) and d.train == (8, 4) and d.threshold_db == 15.0
    assert d.average == "caso"
    assert d.peak_grouping and not d.clutter_removal
    assert DspConfig.from_cfg(radar_cfg, cfar="os").cfar == "os"


def test_range_bias_and_channel_phase_calibration(radar_cfg):
    """A board with a phase error on TX1's channels and a 0.2 m range bias, corrected by the cfg."""
    geom, dsp = make_dsp(radar_cfg)
    t = Target(20.0, 1.0, 20.0, 5.0)
    cube = synth_cube(radar_cfg.chirp, geom, [t], quantise=False)
    err = np.ones(12, dtype=np.complex64)
    err[4:8] = np.exp(1j * 0.8)
    bad = cube * err[None, :, None]
    cal = " ".join(f"{z.real:.5f} {z.imag:.5f}" for z in np.conj(err))
    text = "\n".join(
        line
        for line in open(radar_cfg.path).read().splitlines()
        if not line.startswith("sensorStart")
    )
    cfg2 = parse_cfg(text + f"\ncompRangeBiasAndRxChanPhase 0.0 {cal}\n", "<cal>")
    _, dsp2 = make_dsp(cfg2)
    assert _match(dsp.process(bad).points, t, radar_cfg.chirp)[3] > 5.0  # elevation is off
    assert _match(dsp2.process(bad).points, t, radar_cfg.chirp)[3] <= 2.0


TWO_LANE_CFG = """
sensorStop
flushCfg
dfeDataOutputMode 1
channelCfg 15 5 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 7 6 60 0 0 20 1 128 6000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 4
frameCfg 0 1 64 0 50 1 0
cfarCfg -1 0 2 8 4 3 0 15 1
cfarCfg -1 1 0 4 2 3 1 15 1
sensorStart
"""


def test_two_lane_two_tx_capture(caplog):
    """xWR18xx style: 2-lane layout, TX0 + TX2 (8-element azimuth array, no elevation)."""
    with caplog.at_level(logging.ERROR, logger="mmatch.drivers.ti.cfg"):
        cfg = parse_cfg(TWO_LANE_CFG, "<2lane>")
    geom, dsp = make_dsp(cfg, "2lane")
    assert geom.tx_order == (0, 2) and geom.frame_bytes == 128 * 4 * 128 * 4
    targets = [Target(6.0, 1.0, -25.0), Target(12.0, -2.0, 40.0)]
    raw = cube_to_raw(synth_cube(cfg.chirp, geom, targets), geom)
    pts = dsp.process(raw_to_cube(raw, geom)).points
    assert len(pts) == 2
    for t in targets:
        dr, dv, daz, _ = _match(pts, t, cfg.chirp)
        assert dr <= 1.0 and dv <= 1.0 and daz <= 2.0
    assert np.allclose(pts[:, 2], 0.0)


def test_cube_shape_mismatch_is_an_error(dsp_setup):
    from mmatch.errors import ConfigError

    _, geom, dsp = dsp_setup
    with pytest.raises(ConfigError, match="does not match the cfg"):
        dsp.process(np.zeros((64, 12, 256), dtype=np.complex64))
    assert isinstance(dsp, RadarDsp) and isinstance(geom, FrameGeometry)


PROJECT_CFGS = sorted((Path(__file__).parents[2] / "cfg" / "radar").glob("*.cfg"))


@pytest.mark.skipif(not PROJECT_CFGS, reason="no cfg/radar/*.cfg in this checkout")
@pytest.mark.parametrize("path", PROJECT_CFGS, ids=lambda p: p.name)
def test_the_uart_path_cfgs_drive_the_dsp(path, caplog):
    """The vehicle cfgs of the UART path, recorded raw over 2 lanes, give the same targets."""
    from mmatch.drivers.dca1000.antenna import LAYOUTS
    from mmatch.drivers.ti.cfg import load_cfg

    with caplog.at_level(logging.ERROR, logger="mmatch.drivers.ti.cfg"):
        cfg = load_cfg(path)
    c = cfg.chirp
    antenna = LAYOUTS["xwr16xxboost"] if c.tx_order == (0, 1) else LAYOUTS["awr1843boost"]
    geom, dsp = make_dsp(cfg, "2lane", antenna)
    targets = [Target(30.0, 0.7 * c.max_velocity_mps, 25.0), Target(60.0, -5.0, -30.0)]
    raw = cube_to_raw(synth_cube(c, geom, targets, antenna), geom)
    pts = dsp.process(raw_to_cube(raw, geom)).points
    assert len(pts) == 2
    for t in targets:
        dr, dv, daz, _ = _match(pts, t, c)
        assert dr <= 1.0 and dv <= 1.0 and daz <= 2.0


def test_mirrored_board_flips_x_unless_declared(radar_cfg):
    from mmatch.drivers.dca1000.antenna import AWR2243BOOST

    mirrored = AWR2243BOOST.mirror_x()
    geom, plain = make_dsp(radar_cfg)
    _, declared = make_dsp(radar_cfg, antenna=mirrored)
    t = Target(20.0, 1.0, 30.0)
    cube = synth_cube(radar_cfg.chirp, geom, [t], mirrored)  # a board wired the other way
    assert declared.process(cube).points[0, 0] > 5.0
    assert plain.process(cube).points[0, 0] < -5.0


def test_cli_antenna_choices_are_the_layouts():
    import argparse

    from mmatch.drivers.dca1000.antenna import LAYOUTS
    from mmatch.edge.commands import dsp as cmd

    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    action = next(a for a in p._actions if a.dest == "antenna")
    assert sorted(action.choices) == sorted(LAYOUTS)


def test_angles_match_ti_demo_formulas(dsp_setup):
    """TI's mmw demo AoA, written out: azimuth FFT over TX0+TX2 channels in index order,
    Wx = 2 k / N, x = range * Wx; Wz = arg(Az * conj(El)) / pi + 2 Wx with El the FFT of TX1's
    channels. Our points must agree in value and sign, so raw and UART paths share conventions."""
    import scipy.fft as sfft

    cfg, geom, dsp = dsp_setup
    n = 64
    for t in [
        Target(20.0, 3.0, 30.0, 10.0),
        Target(35.0, -7.0, -45.0, -8.0),
        Target(12.0, 0, 8.0, 0),
    ]:
        cube = synth_cube(cfg.chirp, geom, [t])
        res = dsp.process(cube)
        assert len(res.points) == 1
        x, _, z, _, _ = res.points[0]
        rng = float(np.linalg.norm(res.points[0, :3]))
        d, r = res.cells[0]
        ds = d if d < geom.num_loops // 2 else d - geom.num_loops
        y = dsp.range_doppler(cube)[d, :, r]  # TX0 RX0-3, TX1 RX0-3, TX2 RX0-3
        y = y * np.exp(-2j * np.pi * ds * np.repeat(np.arange(3), 4) / (geom.num_loops * 3))
        az = sfft.fft(np.concatenate([y[0:4], y[8:12]]), n)  # TI's 8 azimuth antennas
        el = sfft.fft(y[4:8], n)  # TI's 4 elevation antennas
        k = int(np.argmax(np.abs(az)))
        ks = k - n if k > n // 2 - 1 else k
        wx = 2 * ks / n
        wz = np.angle(az[k] * np.conj(el[k])) / np.pi + 2 * wx
        wz = wz - 2 if wz > 1 else wz + 2 if wz < -1 else wz
        assert abs(x / rng - wx) <= 2 / n, (t, x / rng, wx)
        assert abs(z / rng - wz) <= 3 * 2 / n, (t, z / rng, wz)
        assert np.sign(x) == np.sign(wx) and np.sign(z) == np.sign(wz)


def test_multi_object_beamforming_splits_a_cell_by_azimuth(radar_cfg):
    """Two cars side by side at the same range and speed share one range-Doppler cell."""
    c = radar_cfg.chirp
    pair = [Target(30.0, 5.0, -25.0), Target(30.0, 5.0, 20.0)]
    geom, single = make_dsp(radar_cfg)
    _, multi = make_dsp(radar_cfg, multi_obj_threshold=0.5)
    cube = synth_cube(c, geom, pair)
    assert len(single.process(cube).points) == 1
    res = multi.process(cube)
    assert len(res.points) == 2 and (res.cells[0] == res.cells[1]).all()
    az = np.sort(np.degrees(np.arctan2(res.points[:, 0], res.points[:, 1])))
    assert abs(az[0] + 25.0) <= 2.0 and abs(az[1] - 20.0) <= 2.0
    lone = multi.process(synth_cube(c, geom, [Target(30.0, 5.0, 35.0)])).points
    assert len(lone) == 1  # sidelobes of one target never make a second point


def test_multi_object_setting_from_cfg(radar_cfg):
    text = (
        open(radar_cfg.path)
        .read()
        .replace("sensorStart", "multiObjBeamForming -1 1 0.5\nsensorStart")
    )
    assert DspConfig.from_cfg(parse_cfg(text, "<mobf>")).multi_obj_threshold == 0.5
    assert DspConfig.from_cfg(radar_cfg).multi_obj_threshold is None


@pytest.mark.parametrize(("adc", "why"), [("adcCfg 1 1", "16-bit"), ("adcCfg 2 0", "real-only")])
def test_adc_formats_the_raw_path_cannot_read_are_refused(radar_cfg, adc, why):
    from mmatch.errors import ConfigError

    text = open(radar_cfg.path).read().replace("adcCfg 2 1", adc)
    with pytest.raises(ConfigError, match=why):
        make_dsp(parse_cfg(text, "<adc>"))


def test_tdm_compensation_uses_the_sub_bin_doppler(radar_cfg):
    """Half a Doppler bin off the grid, compensating the TX slots with the whole bin only leaves
    0.07 deg of azimuth error at 40 deg (TX2 fires 2 Tc after TX0); the sub-bin Doppler removes
    it."""
    geom, dsp = make_dsp(radar_cfg)
    for k in (3, -7, 12):
        for frac in (0.0, 0.25, 0.5):
            t = Target(25.0, (k + frac) * dsp.doppler_step, 40.0, 5.0, 20.0)
            cube = synth_cube(radar_cfg.chirp, geom, [t], quantise=False, noise_lsb=0.01)
            pts = dsp.process(cube).points
            assert len(pts) == 1
            _, _, daz, del_ = _match(pts, t, radar_cfg.chirp)
            assert daz < 0.01 and del_ < 0.03, (k, frac, daz, del_)
