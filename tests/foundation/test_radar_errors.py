"""The simulator's angle error model (mmatch/sim/radar_errors.py): bounds, glint, calibration,
spec ranges. Its match to our own DSP is tests/dca1000/test_angle_model.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mmatch.errors import ConfigError
from mmatch.sim.radar_errors import (
    ANGLE_SPEC_RANGES,
    AngleErrorSpec,
    angle_sigma,
    channel_snr,
    draw_angle_errors,
    draw_angle_spec,
    noise_sigma,
)

N = 8000


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_point_target_errors_follow_the_cramer_rao_bound():
    rng = np.random.default_rng(0)
    for az_deg in (0.0, 30.0, 60.0):
        az = math.radians(az_deg)
        d_az, d_el = draw_angle_errors(rng, np.full(N, 20.0), az, 0.0)
        s_az, s_el = noise_sigma(20.0, az, 0.0)
        assert _rms(d_az) == pytest.approx(float(s_az), rel=0.08), az_deg
        assert _rms(d_el) == pytest.approx(float(s_el), rel=0.08), az_deg
    # 1/cos(az): twice the error at 60 deg
    assert float(noise_sigma(20.0, math.radians(60))[0] / noise_sigma(20.0, 0.0)[0]) == (
        pytest.approx(2.0, rel=1e-9)
    )


def test_bound_values_of_an_eight_channel_array():
    """8 channels, 15 dB reported (s = 30.6): sigma_u = sqrt(6 / (s 8 63)) / pi = 0.0063."""
    s = float(channel_snr(15.0))
    assert s == pytest.approx(10**1.5 - 1)
    want = math.degrees(math.sqrt(6 / (s * 8 * 63)) / math.pi)
    assert math.degrees(float(noise_sigma(15.0, 0.0)[0])) == pytest.approx(want, rel=1e-9)
    assert 0.3 < want < 0.4
    # more channels, smaller errors: (8 * 63 / (12 * 143)) ** 0.5
    twelve = AngleErrorSpec(channels_az=12)
    ratio = float(noise_sigma(15.0, 0.0, spec=twelve)[0] / noise_sigma(15.0, 0.0)[0])
    assert ratio == pytest.approx(math.sqrt(8 * 63 / (12 * 143)), rel=1e-9)
    # and the errors drawn shrink with it
    rng = np.random.default_rng(1)
    e8 = _rms(draw_angle_errors(rng, np.full(N, 15.0), 0.0, 0.0)[0])
    e12 = _rms(draw_angle_errors(rng, np.full(N, 15.0), 0.0, 0.0, spec=twelve)[0])
    assert e12 / e8 == pytest.approx(ratio, rel=0.1)


def test_errors_fall_with_snr():
    rng = np.random.default_rng(2)
    med = [
        float(np.median(np.abs(draw_angle_errors(rng, np.full(N, snr), 0.2, 0.0)[0])))
        for snr in (6.0, 12.0, 20.0, 30.0)
    ]
    assert med == sorted(med, reverse=True)
    assert med[0] > 5 * med[-1]


def test_glint_of_a_car_face_at_30_m():
    """A 2 m face at 30 m spans 3.8 deg: at high SNR the error is glint, inside the extent
    mostly (median about 0.2 x extent), and grows with the extent; a point target has none."""
    rng = np.random.default_rng(3)
    ext = 2.0 / 30.0
    d_az, _ = draw_angle_errors(rng, np.full(N, 60.0), 0.1, 0.0, ext, 0.0)
    med = float(np.median(np.abs(d_az)))
    p90 = float(np.percentile(np.abs(d_az), 90))
    assert 0.15 * ext < med < 0.26 * ext
    assert 0.4 * ext < p90 < 0.65 * ext
    wide, _ = draw_angle_errors(rng, np.full(N, 60.0), 0.1, 0.0, 2 * ext, 0.0)
    assert float(np.median(np.abs(wide))) == pytest.approx(2 * med, rel=0.12)
    point, _ = draw_angle_errors(rng, np.full(N, 60.0), 0.1, 0.0, 0.0, 0.0)
    assert float(np.median(np.abs(point))) < 0.02 * med
    # glint_factor scales it
    half, _ = draw_angle_errors(
        rng, np.full(N, 60.0), 0.1, 0.0, ext, 0.0, AngleErrorSpec(glint_factor=0.5)
    )
    assert float(np.median(np.abs(half))) == pytest.approx(0.5 * med, rel=0.12)


def test_vehicle_returns_at_15_db_are_one_to_two_degrees_off():
    """The issue's figure: TI-class arrays on vehicle returns give 1-2 deg at boresight."""
    rng = np.random.default_rng(4)
    d_az, _ = draw_angle_errors(rng, np.full(N, 15.0), 0.0, 0.0, 2.0 / 30.0, 1.0 / 30.0)
    deg = np.degrees(np.abs(d_az))
    assert 0.6 < float(np.median(deg)) < 1.2
    assert 1.5 < float(np.percentile(deg, 90)) < 3.0


def test_calibration_bias_and_floor():
    rng = np.random.default_rng(5)
    spec = AngleErrorSpec(calib_bias_az_deg=0.4, calib_bias_el_deg=-0.8)
    d_az, d_el = draw_angle_errors(rng, np.full(N, 40.0), 0.0, 0.0, spec=spec)
    assert math.degrees(float(np.mean(d_az))) == pytest.approx(0.4, abs=0.01)
    assert math.degrees(float(np.mean(d_el))) == pytest.approx(-0.8, abs=0.02)
    floor = AngleErrorSpec(calib_floor_az_deg=0.5, calib_floor_el_deg=1.0)
    d_az, d_el = draw_angle_errors(rng, np.full(N, 40.0), 0.0, 0.0, spec=floor)
    assert math.degrees(_rms(d_az)) == pytest.approx(0.5, rel=0.06)
    assert math.degrees(_rms(d_el)) == pytest.approx(1.0, rel=0.06)


def test_array_without_elevation_reports_the_horizontal_plane():
    rng = np.random.default_rng(6)
    el = np.radians(np.array([-6.0, 0.0, 4.0, 9.0]))
    spec = AngleErrorSpec(channels_el=0)
    _, d_el = draw_angle_errors(rng, 30.0, 0.0, el, spec=spec)
    assert np.allclose(d_el, -el, atol=1e-9)
    assert np.all(angle_sigma(30.0, 0.0, el, spec=spec)[1] == 0)


def test_shapes_broadcast_and_empty_input():
    rng = np.random.default_rng(7)
    d_az, d_el = draw_angle_errors(rng, np.full((3, 4), 20.0), np.zeros(4), 0.0, 0.05, 0.02)
    assert d_az.shape == d_el.shape == (3, 4)
    d_az, d_el = draw_angle_errors(rng, np.zeros(0), np.zeros(0), np.zeros(0))
    assert d_az.shape == d_el.shape == (0,)
    s_az, s_el = angle_sigma(np.array([10.0, 20.0]), 0.0)
    assert s_az.shape == s_el.shape == (2,)


def test_angle_sigma_matches_the_drawn_errors():
    """Point target: the bound; wide target at high SNR: the glint's Gaussian-equivalent scale."""
    rng = np.random.default_rng(8)
    assert np.allclose(angle_sigma(20.0, 0.3)[0], noise_sigma(20.0, 0.3)[0])
    ext = 0.06
    d_az, _ = draw_angle_errors(rng, np.full(N, 60.0), 0.0, 0.0, ext, 0.0)
    robust = float(np.median(np.abs(d_az))) / 0.6745
    assert float(angle_sigma(60.0, 0.0, 0.0, ext)[0]) == pytest.approx(robust, rel=0.12)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("channels_az", 1),
        ("channels_el", -1),
        ("row_offset", 0.0),
        ("glint_factor", -0.1),
        ("calib_floor_az_deg", -1.0),
        ("calib_floor_el_deg", math.nan),
        ("calib_bias_az_deg", math.inf),
        ("glint_scatterers", (3, 2)),
    ],
)
def test_impossible_constants_are_refused_naming_the_field(field, value):
    with pytest.raises(ConfigError, match=field):
        AngleErrorSpec(**{field: value})


def test_draw_angle_spec_stays_in_its_ranges():
    rng = np.random.default_rng(9)
    specs = [draw_angle_spec(rng) for _ in range(200)]
    for key, (lo, hi) in ANGLE_SPEC_RANGES.items():
        vals = [getattr(s, key) for s in specs]
        assert lo <= min(vals) and max(vals) <= hi, key
        assert max(vals) > min(vals), key
    assert {s.channels_az for s in specs} == set(range(8, 13))
    a = draw_angle_spec(np.random.default_rng(1))
    assert a == draw_angle_spec(np.random.default_rng(1))


@pytest.mark.parametrize(
    ("ranges", "key"),
    [
        ({"glint_factor": (1.2, 0.8)}, "glint_factor"),
        ({"calib_floor_az_deg": (-1.0, -0.5)}, "calib_floor_az_deg"),
        ({"no_such_constant": (0, 1)}, "no_such_constant"),
        ({"channels_el": (2.2, 2.8)}, "channels_el"),
        ({"calib_bias_az_deg": (0.0, math.nan)}, "calib_bias_az_deg"),
        ({"glint_factor": "wide"}, "glint_factor"),
    ],
)
def test_bad_ranges_are_refused_naming_the_key(ranges, key):
    with pytest.raises(ConfigError, match=key):
        draw_angle_spec(np.random.default_rng(0), ranges)
