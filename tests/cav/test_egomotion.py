"""Doppler ego-motion: exact on clean data, <= 0.2 m/s median on realistic frames, never raises."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.cav.config import CavConfig, EgoMotionConfig
from mmatch.cav.egomotion import EgoStatus, fit_egomotion, stationary_doppler
from mmatch.errors import ConfigError

from .synth import STATIONARY, make_frame


def clean_points(v, n=60, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(-1.0, 1.0, n)
    r = rng.uniform(3, 80, n)
    z = rng.uniform(-1, 2, n)
    xyz = np.column_stack([r * np.sin(az), r * np.cos(az), z])
    pts = np.column_stack([xyz, np.zeros(n), np.full(n, 15.0)]).astype(np.float32)
    pts[:, 3] = stationary_doppler(pts, v)
    return pts


def test_exact_on_noise_free_stationary_points():
    v = np.array([0.9, 14.2])
    e = fit_egomotion(clean_points(v))
    assert e.ok and e.inliers == 60
    np.testing.assert_allclose(e.velocity, v, atol=1e-4)
    assert not e.moving.any()
    assert np.abs(e.residual).max() < 1e-3


def test_doppler_sign_convention_matches_design():
    # driving forward at 10 m/s, a post straight ahead approaches: doppler -10 (range decreasing)
    pts = np.array([[0, 20, 0, 0, 0], [20, 0.0, 0, 0, 0]], np.float32)
    np.testing.assert_allclose(stationary_doppler(pts, [0.0, 10.0]), [-10.0, 0.0], atol=1e-9)


def test_moving_points_are_flagged_and_do_not_bias_the_fit():
    v = np.array([-0.5, 12.0])
    pts = clean_points(v, n=80)
    pts[:25, 3] += np.random.default_rng(1).uniform(2, 15, 25) * np.sign(np.random.default_rng(2).normal(size=25))
    e = fit_egomotion(pts)
    assert e.ok
    np.testing.assert_allclose(e.velocity, v, atol=1e-3)
    assert e.moving[:25].all() and not e.moving[25:].any()


def test_velocity_error_and_moving_labels_on_synthetic_frames():
    errs, tp, fp, fn, false_stationary, n_stationary = [], 0, 0, 0, 0, 0
    for seed in range(60):
        f = make_frame(seed, n_moving=2 + seed % 9, perpendicular=seed % 3 == 0)
        e = fit_egomotion(f.points)
        assert e.ok
        errs.append(np.linalg.norm(e.velocity - f.velocity))
        gt = f.gt_moving
        tp += np.sum(e.moving & gt)
        fp += np.sum(e.moving & ~gt)
        fn += np.sum(~e.moving & gt)
        stat = f.labels == STATIONARY
        false_stationary += np.sum(e.moving & stat)
        n_stationary += stat.sum()
    errs = np.array(errs)
    recall = tp / (tp + fn)
    print(f"\nego-motion on 60 synthetic frames: |v err| median {np.median(errs):.3f} m/s, "
          f"p90 {np.percentile(errs, 90):.3f}; moving recall {recall:.3f}, precision {tp / (tp + fp):.3f} "
          f"(ghosts and clutter count as false); stationary called moving {false_stationary / n_stationary:.3f}")
    assert np.median(errs) <= 0.2
    assert np.percentile(errs, 90) <= 0.4
    assert recall >= 0.95                      # only perpendicular crossers may look stationary
    assert false_stationary / n_stationary <= 0.05


@pytest.mark.parametrize("points, status", [
    (np.zeros((0, 5), np.float32), EgoStatus.TOO_FEW_POINTS),
    (np.array([[1, 10, 0, -9, 10], [-1, 10, 0, -9, 10]], np.float32), EgoStatus.TOO_FEW_POINTS),
    (np.array([[1, 10, 0, -9, 10]] * 3 + [[np.nan, 1, 1, 1, 1]], np.float32), EgoStatus.DEGENERATE_BEARING),
    (np.array([[0.0, r, 0, -9, 10] for r in range(5, 40)], np.float32), EgoStatus.DEGENERATE_BEARING),
    (np.array([[np.nan, 1, 0, 0, 0]] * 10, np.float32), EgoStatus.TOO_FEW_POINTS),
])
def test_degenerate_frames_give_a_status_not_an_exception(points, status):
    e = fit_egomotion(points)
    assert e.status is status and not e.ok and e.reason
    assert np.all(np.isnan(e.velocity))
    assert e.moving.shape == (len(points),) and not e.moving.any()
    assert e.residual.shape == (len(points),)


def test_no_consensus_when_dopplers_are_random():
    rng = np.random.default_rng(3)
    pts = clean_points(np.array([0.0, 10.0]), n=30)
    pts[:, 3] = rng.uniform(-30, 30, 30)
    e = fit_egomotion(pts, EgoMotionConfig(min_inliers=10))
    assert e.status is EgoStatus.NO_CONSENSUS and not e.moving.any()


def test_non_finite_rows_are_ignored():
    v = np.array([0.3, 9.0])
    pts = clean_points(v, n=40)
    pts[5, 0] = np.nan
    pts[7, 3] = np.inf
    e = fit_egomotion(pts)
    assert e.ok and not e.moving[[5, 7]].any()
    np.testing.assert_allclose(e.velocity, v, atol=1e-3)


def test_fit_is_deterministic():
    f = make_frame(11)
    a, b = fit_egomotion(f.points), fit_egomotion(f.points)
    np.testing.assert_array_equal(a.velocity, b.velocity)
    np.testing.assert_array_equal(a.moving, b.moving)


def test_config_rejects_unknown_keys_and_bad_values():
    cfg = CavConfig.from_dict({"egomotion": {"threshold_mps": 0.5}, "background": {"max_points": 100}})
    assert cfg.egomotion.threshold_mps == 0.5 and cfg.background.max_points == 100
    with pytest.raises(ConfigError, match="egomotion.treshold"):
        CavConfig.from_dict({"egomotion": {"treshold": 1}})
    with pytest.raises(ConfigError, match="nonsense"):
        CavConfig.from_dict({"nonsense": {}})
    with pytest.raises(ConfigError, match="threshold_mps"):
        CavConfig.from_dict({"egomotion": {"threshold_mps": -1}})
    with pytest.raises(ConfigError, match="min_points"):
        CavConfig(egomotion=EgoMotionConfig(min_points=2))
    with pytest.raises(ConfigError, match="wire format"):
        CavConfig.from_dict({"inputs": {"max_range_m": 400}})
    with pytest.raises(ConfigError, match="inputs.max_points"):
        CavConfig.from_dict({"inputs": {"max_points": -1}})
    with pytest.raises(ConfigError, match="inputs.unknown_depth_height_m"):
        CavConfig.from_dict({"inputs": {"unknown_depth_height_m": -1.5}})
    assert CavConfig.from_dict({"inputs": {"max_points": 0, "unknown_depth_height_m": 0}}).inputs.max_points == 0


def test_forward_motion_prior_rejects_a_platoon_only_frame():
    # the only consistent points are vehicles driving with us: they look like a radar backing up
    platoon = clean_points(np.array([0.2, -6.0]), n=12)
    e = fit_egomotion(platoon)
    assert e.status is EgoStatus.NO_CONSENSUS and "forward" in e.reason
    e = fit_egomotion(platoon, EgoMotionConfig(min_forward_mps=-np.inf))    # a rear-facing radar
    assert e.ok and np.allclose(e.velocity, [0.2, -6.0], atol=1e-3)
    # with the background present the prior changes nothing
    pts = np.vstack([platoon, clean_points(np.array([0.2, 12.0]), n=10, seed=5)])
    e = fit_egomotion(pts)
    assert e.ok and np.allclose(e.velocity, [0.2, 12.0], atol=1e-3)
    assert e.moving[:12].all() and not e.moving[12:].any()
