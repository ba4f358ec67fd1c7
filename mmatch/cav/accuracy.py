"""How well the radar measures each point: angle and Doppler standard deviations from its SNR.

The CAV side sizes its tests from these instead of fixed margins: a stationary point's
Doppler is predicted from its azimuth, so an azimuth error of sigma_az moves the
prediction by |d doppler / d az| * sigma_az (the radar's own speed times the sine of the
azimuth: 0.2 m/s at 30 deg, 15 m/s and 1.5 deg); a vehicle's returns scatter across its
bearing by sigma_az times the range.

Model (per point, radians and m/s; SNR as the radar reports it, dB):
- azimuth: the array bound of a uniform half-wavelength array of N channels,
  sqrt(6 / (pi^2 N (N^2 - 1) SNR)) / cos(az), times `bound_scale`, in quadrature with a
  calibration floor (the residual every calibrated array keeps) and, for a vehicle,
  glint over its angular extent;
- elevation: the same with the elevation channels;
- Doppler: `doppler_mps` at high SNR, growing as the amplitude below `reference_snr_db`.
The constants are a belief about the radar at hand (a config section), not its truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.types import SNR, X, Y, Z


@dataclass(frozen=True)
class RadarAccuracyConfig:
    """What the CAV side believes about its radar's accuracy.

    channels_az / channels_el: virtual channels across azimuth / elevation.
    bound_scale: factor on the array bound (real detections sit above it).
    floor_az_deg / floor_el_deg: calibration residual, deg (1 sigma).
    glint_share: angle wander of a vehicle as a share of its angular extent (1 sigma).
    doppler_mps: Doppler standard deviation at high SNR, m/s.
    reference_snr_db: below this SNR the range and Doppler errors grow with the amplitude ratio.
    min_snr_db: SNR values below this (or missing: 0) are read as this.
    """

    channels_az: int = 8
    channels_el: int = 2
    bound_scale: float = 1.3
    floor_az_deg: float = 0.9
    floor_el_deg: float = 1.5
    glint_share: float = 0.15
    doppler_mps: float = 0.1
    reference_snr_db: float = 15.0
    min_snr_db: float = 5.0


def array_bound(snr_db: np.ndarray, angle: np.ndarray, channels: int) -> np.ndarray:
    """Cramer-Rao bound (rad) of a point target's angle on a uniform half-wavelength array."""
    snr = 10.0 ** (np.clip(np.asarray(snr_db, np.float64), -30.0, 90.0) / 10.0)
    n = max(float(channels), 2.0)
    return np.sqrt(6.0 / (np.pi ** 2 * n * (n * n - 1.0) * snr)) / np.maximum(np.cos(angle), 0.2)


def _snr(points: np.ndarray, cfg: RadarAccuracyConfig) -> np.ndarray:
    s = np.asarray(points[:, SNR], np.float64) if points.shape[1] > SNR else np.zeros(len(points))
    return np.clip(np.where(np.isfinite(s), s, 0.0), cfg.min_snr_db, 90.0)


def sigma_azimuth(points: np.ndarray, cfg: RadarAccuracyConfig = RadarAccuracyConfig()) -> np.ndarray:
    """Azimuth standard deviation (N,) rad of each point (N, 5), point-like targets."""
    az = np.arctan2(points[:, X], points[:, Y]).astype(np.float64)
    bound = cfg.bound_scale * array_bound(_snr(points, cfg), az, cfg.channels_az)
    return np.hypot(bound, np.radians(cfg.floor_az_deg))


def sigma_elevation(points: np.ndarray, cfg: RadarAccuracyConfig = RadarAccuracyConfig()) -> np.ndarray:
    """Elevation standard deviation (N,) rad of each point (N, 5)."""
    el = np.arctan2(points[:, Z], np.hypot(points[:, X], points[:, Y])).astype(np.float64)
    bound = cfg.bound_scale * array_bound(_snr(points, cfg), el, cfg.channels_el)
    return np.hypot(bound, np.radians(cfg.floor_el_deg))


def sigma_doppler(points: np.ndarray, cfg: RadarAccuracyConfig = RadarAccuracyConfig()) -> np.ndarray:
    """Doppler standard deviation (N,) m/s of each point (N, 5)."""
    weak = np.maximum(1.0, 10.0 ** ((cfg.reference_snr_db - _snr(points, cfg)) / 20.0))
    return cfg.doppler_mps * weak


def stationary_doppler_sigma(points: np.ndarray, velocity: np.ndarray,
                             cfg: RadarAccuracyConfig = RadarAccuracyConfig()) -> np.ndarray:
    """Standard deviation (N,) m/s of a stationary point's Doppler residual under radar velocity (vx, vy).

    The residual doppler + vx sin(az) + vy cos(az) carries the Doppler noise plus the
    azimuth error times |d doppler / d az| = |vx cos(az) - vy sin(az)|.
    """
    az = np.arctan2(points[:, X], points[:, Y]).astype(np.float64)
    vx, vy = float(velocity[0]), float(velocity[1])
    slope = np.abs(vx * np.cos(az) - vy * np.sin(az))
    return np.hypot(sigma_doppler(points, cfg), slope * sigma_azimuth(points, cfg))
