"""The DSP finds weak far targets beside stronger ones (issue 10).

Seen from a radar driving at 12 m/s, every stationary reflector near boresight lies in the same
Doppler bin (-v cos(az)), so far down the road a weak reflector often has a stronger one a few
range bins away in its own Doppler bin: the mean over the whole CFAR ring (CA) then masks it, and
two range bins away the 3 x 3 peak grouping drops it. The cfg asks for the smaller-half mean in
range (cfarCfg averageMode 2, CASO), and peak grouping now tells a target at another angle from a
stronger target's leakage by the channel vector; Hann sidelobes of strong targets, which CASO
would otherwise pass on zero-padded cfgs, are dropped the same way.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest

from mmatch.drivers.dca1000.antenna import LAYOUTS
from mmatch.drivers.dca1000.dsp import make_dsp
from mmatch.drivers.dca1000.synth import Target, synth_cube
from mmatch.drivers.ti.cfg import load_cfg

SPEED = 12.0  # m/s, radar driving along +y
OLD = dict(average="ca", signature_grouping=False)  # whole-ring CA, power-only peak grouping


def stationary(range_m: float, az_deg: float, snr_db: float, el_deg: float = 0.0) -> Target:
    """A stationary reflector seen from the moving radar (Doppler -v cos(az) cos(el))."""
    dop = -SPEED * math.cos(math.radians(az_deg)) * math.cos(math.radians(el_deg))
    return Target(range_m, dop, az_deg, el_deg, snr_db)


def found(points: np.ndarray, t: Target, dsp, max_az_deg: float = 2.0) -> bool:
    """A point within one range bin, one Doppler bin and max_az_deg of target t."""
    if not len(points):
        return False
    r = np.linalg.norm(points[:, :3], axis=1)
    az = np.degrees(np.arctan2(points[:, 0], points[:, 1]))
    ok = (
        (np.abs(r - t.range_m) <= dsp.range_step)
        & (np.abs(points[:, 3] - t.velocity_mps) <= dsp.doppler_step)
        & (np.abs(az - t.azimuth_deg) <= max_az_deg)
    )
    return bool(ok.any())


@pytest.mark.parametrize(("bins", "stronger_db"), [(6.3, 6.0), (6.3, 20.0), (9.3, 10.0)])
def test_a_stronger_reflector_in_the_same_doppler_bin_no_longer_masks(radar_cfg, bins, stronger_db):
    """At 90 % of the maximum range and 40 deg off boresight, a reflector about 25 dB over the
    noise, and a stronger one a few bins farther at -40 deg (the same Doppler bin)."""
    c = radar_cfg.chirp
    geom, dsp = make_dsp(radar_cfg)
    _, old = make_dsp(radar_cfg, **OLD)
    weak_r = 0.9 * c.max_range_m
    weak = stationary(weak_r, 40.0, -17.0)
    strong = stationary(weak_r + bins * dsp.range_step, -40.0, -17.0 + stronger_db)
    for seed in range(3):
        cube = synth_cube(c, geom, [weak, strong], rng=np.random.default_rng(seed))
        pts = dsp.process(cube).points
        assert len(pts) == 2 and found(pts, weak, dsp) and found(pts, strong, dsp), pts
        snr_weak = pts[np.argmin(np.abs(np.linalg.norm(pts[:, :3], axis=1) - weak_r)), 4]
        assert 20.0 < snr_weak < 30.0  # its SNR over the noise, not over the neighbour
        was = old.process(cube).points
        assert not found(was, weak, dsp) and found(was, strong, dsp)


def test_a_weaker_reflector_two_bins_away_at_another_angle_is_kept(radar_cfg):
    """Two range bins from a reflector 20 dB stronger, in the same Doppler bin: not a local
    maximum of the power, but its channel vector points elsewhere (40 vs -40 deg)."""
    c = radar_cfg.chirp
    geom, dsp = make_dsp(radar_cfg)
    _, old = make_dsp(radar_cfg, **OLD)
    weak = stationary(0.9 * c.max_range_m, 40.0, -17.0)
    strong = stationary(weak.range_m + 2.3 * dsp.range_step, -40.0, 3.0)
    for seed in range(3):
        cube = synth_cube(c, geom, [weak, strong], rng=np.random.default_rng(seed))
        pts = dsp.process(cube).points
        assert len(pts) == 2 and found(pts, weak, dsp) and found(pts, strong, dsp)
        assert not found(old.process(cube).points, weak, dsp)
    # at nearly the same angle (40 vs 32 deg) the two are one blob: still one point
    close = stationary(weak.range_m + 2.3 * dsp.range_step, 32.0, 3.0)
    close = Target(close.range_m, weak.velocity_mps, 32.0, 0.0, 3.0)
    pts = dsp.process(synth_cube(c, geom, [weak, close])).points
    assert len(pts) == 1 and found(pts, close, dsp)


def test_road_at_12_mps_far_reflectors_beside_strong_signs(radar_cfg):
    """36 targets: posts on both roadsides, strong signs, cars; two weak posts beyond 65 m each
    have a sign 6-7 range bins nearer on the other side of the road (same Doppler bin). Every
    target is found; the old CFAR lost those two and five more posts masked the same way."""
    c = radar_cfg.chirp
    geom, dsp = make_dsp(radar_cfg)
    _, old = make_dsp(radar_cfg, **OLD)
    rng = np.random.default_rng(7)

    def at(x: float, y: float, z: float, snr: float) -> Target:
        r = math.sqrt(x * x + y * y + z * z)
        return stationary(r, math.degrees(math.atan2(x, y)), snr, math.degrees(math.asin(z / r)))

    def radar_eq(r: float, rcs_db: float) -> float:
        return rcs_db - 40.0 * math.log10(r / 10.0)

    posts = []
    for k, y in enumerate(np.arange(9.0, 100.0, 8.0)):  # 12 per side, staggered
        for side, dy in ((-1, 0.0), (1, 4.0)):
            x, yy = side * (5.5 + 0.7 * (k % 3)), y + dy
            if len(posts) < 22:
                posts.append(at(x, yy, 0.3, radar_eq(math.hypot(x, yy), 17.0)))
    far_weak = [p for p in posts if p.range_m > 65.0][:4:3]  # two of the far posts
    signs = [
        at(6.0 if p.azimuth_deg < 0 else -6.0, p.range_m - 6.5 * dsp.range_step, 2.0,
           p.snr_db + 12.0)
        for p in far_weak
    ]
    cars = []
    while len(posts) + len(signs) + len(cars) < 36:
        y = float(rng.uniform(15, 90))
        lane = float(rng.choice([-1.75, 1.75]))
        vy = 14.0 if lane > 0 else -6.0
        r = math.hypot(lane, y)
        u = np.array([lane, y]) / r
        cars.append(Target(r, float(u[1] * (vy - SPEED)), math.degrees(math.atan2(lane, y)),
                           0.0, radar_eq(r, 25.0)))
    targets = posts + signs + cars
    assert len(targets) == 36
    for t in far_weak:
        assert t.range_m > 65.0 and t.snr_db + 42.0 > 20.0  # well above the noise
    cube = synth_cube(c, geom, targets, rng=np.random.default_rng(0))
    pts = dsp.process(cube).points
    missed = [t for t in targets if not found(pts, t, dsp, 3.0)]
    assert not missed, missed
    was = old.process(cube).points
    old_missed = [t for t in posts + signs if not found(was, t, dsp, 3.0)]
    assert all(t in old_missed for t in far_weak) and len(old_missed) >= 4, old_missed


PROJECT_CFGS = sorted((Path(__file__).parents[2] / "cfg" / "radar").glob("*.cfg"))


@pytest.mark.parametrize("path", PROJECT_CFGS, ids=lambda p: p.name)
def test_a_very_strong_target_is_one_point(path, caplog):
    """96 samples zero-padded to 128 range bins sample the Hann sidelobes off their nulls: with
    CASO they pass the CFAR as separate peaks; the channel-vector test drops them."""
    with caplog.at_level(logging.ERROR, logger="mmatch.drivers.ti.cfg"):
        cfg = load_cfg(path)
    c = cfg.chirp
    antenna = LAYOUTS["xwr16xxboost"] if c.tx_order == (0, 1) else LAYOUTS["awr1843boost"]
    geom, dsp = make_dsp(cfg, "2lane", antenna, multi_obj_threshold=None)
    _, no_sig = make_dsp(cfg, "2lane", antenna, multi_obj_threshold=None, signature_grouping=False)
    extra_without = 0
    for snr in (20.0, 30.0, 40.0):
        for frac in (0.0, 0.5):
            r, v = (60 + frac) * dsp.range_step, (10 + frac) * dsp.doppler_step
            t = Target(r, v, -40.0, 0.0, snr)
            cube = synth_cube(c, geom, [t], antenna, rng=np.random.default_rng(1))
            pts = dsp.process(cube).points
            assert len(pts) == 1 and found(pts, t, dsp), (snr, frac, pts)
            extra_without += len(no_sig.process(cube).points) - 1
    assert extra_without >= 3
