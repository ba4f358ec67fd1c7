"""FMCW raw-ADC synthesiser: point targets (and vehicles as several scatterers per range-Doppler
cell, `extended_target`) -> complex int16 cube / raw LVDS frames.

Model (complex baseband, TI complex1x: a target appears at a positive beat frequency):
for chirp c (frame order; loop l = c // T, slot k = c % T, TX = tx_order[k]) starting at
t_c = c * Tc (Tc = idle + ramp end time), ADC sample n at t_n = adcStart + n / fs after the ramp
start, and virtual channel position p (lambda/2 units, see antenna.py),

    phase = 2 pi (f0 + S t_n) * 2 R(t_c) / c  -  pi (p . u)        R(t_c) = R0 + v t_c

so the range grows with v > 0 (Doppler positive = range increasing, DESIGN.md) and a target to
the right (u_x > 0) lags on antennas further right. Intra-chirp motion is neglected. The
slow-time factor is computed once per distinct velocity (targets of one velocity share it).
Amplitude: `snr_db` is the target power over the noise power of one complex ADC sample of one
channel (the DSP adds ~10 log10(samples * chirps * channels) of processing gain).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .antenna import AWR2243BOOST, AntennaLayout
from .layout import FrameGeometry, cube_to_raw

C = 3e8


@dataclass(frozen=True)
class Target:
    """A point target: range (m), radial velocity (m/s, + = receding), azimuth and elevation
    (deg; azimuth = atan2(x, y), positive to the right; elevation positive up), SNR (dB)."""

    range_m: float
    velocity_mps: float = 0.0
    azimuth_deg: float = 0.0
    elevation_deg: float = 0.0
    snr_db: float = 20.0

    def xyz(self) -> tuple[float, float, float]:
        az, el = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        return (
            self.range_m * math.sin(az) * math.cos(el),
            self.range_m * math.cos(az) * math.cos(el),
            self.range_m * math.sin(el),
        )


def extended_target(
    rng: np.random.Generator,
    range_m: float,
    velocity_mps: float,
    azimuth_deg: float,
    elevation_deg: float,
    width_m: float,
    height_m: float,
    snr_db: float,
    num_scatterers: int,
    depth_m: float = 0.2,
) -> list[Target]:
    """The part of a vehicle that falls in one range-Doppler cell: `num_scatterers` point
    scatterers spread uniformly over a face `width_m` wide and `height_m` high (centred on
    azimuth/elevation; its angular extent is width / range by height / range) and `depth_m`
    deep (well within a range bin; the sub-wavelength path differences give the scatterers
    independent phases), all at one radial velocity. Their powers are exponentially distributed
    (no scatterer dominates on purpose) and sum to `snr_db` (dB over one ADC sample's noise)."""
    if num_scatterers < 1 or range_m <= 0 or width_m < 0 or height_m < 0:
        raise ValueError("extended_target needs >= 1 scatterer, range > 0, sizes >= 0")
    power = rng.exponential(1.0, num_scatterers)
    power /= power.sum()
    ext_az = math.degrees(width_m / range_m)
    ext_el = math.degrees(height_m / range_m)
    du = rng.uniform(-0.5, 0.5, (num_scatterers, 3))
    return [
        Target(
            range_m + depth_m * du[i, 0],
            velocity_mps,
            azimuth_deg + ext_az * du[i, 1],
            elevation_deg + ext_el * du[i, 2],
            snr_db + 10.0 * math.log10(max(power[i], 1e-12)),
        )
        for i in range(num_scatterers)
    ]


def centre_frequency_hz(chirp) -> float:
    """Frequency (Hz) at the middle of the ADC sampling window; the lambda of the array spacing."""
    mid_us = chirp.adc_start_time_us + 0.5 * chirp.num_adc_samples / (chirp.sample_rate_ksps * 1e-3)
    return chirp.start_freq_ghz * 1e9 + chirp.slope_mhz_per_us * 1e12 * mid_us * 1e-6


def synth_cube(
    chirp,
    geom: FrameGeometry,
    targets: list[Target],
    layout: AntennaLayout = AWR2243BOOST,
    noise_lsb: float = 4.0,
    frame_index: int = 0,
    rng: np.random.Generator | None = None,
    quantise: bool = True,
) -> np.ndarray:
    """complex64 (loops, virtual, samples) ADC cube of one frame, in LSB (int16 values if quantise).

    chirp: drivers.ti.cfg.ChirpParams; geom: FrameGeometry of the same cfg; noise_lsb: std of the
    complex noise per sample (LSB, split over I and Q); frame_index: frames start every
    frame_period_ms, so targets move between frames.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    L, T, N = geom.num_loops, len(geom.tx_order), geom.num_samples
    R = geom.num_rx
    tc = chirp.chirp_time_us * 1e-6
    fs = chirp.sample_rate_ksps * 1e3
    s_hz = chirp.slope_mhz_per_us * 1e12
    f0 = chirp.start_freq_ghz * 1e9
    t_n = chirp.adc_start_time_us * 1e-6 + np.arange(N) / fs  # (N,)
    t_c = np.arange(L * T) * tc + frame_index * chirp.frame_period_ms * 1e-3  # (C,)
    pos = layout.virtual_positions(geom.tx_order, geom.rx).reshape(T, R, 2)  # slot, rx, (x, z)
    cube = np.zeros((L, T, R, N), dtype=np.complex64)
    freq_n = 2.0 * (f0 + s_hz * t_n) / C  # cycles per metre
    if targets:
        rng_m = np.array([tg.range_m for tg in targets])
        vel = np.array([tg.velocity_mps for tg in targets])
        az = np.radians([tg.azimuth_deg for tg in targets])
        el = np.radians([tg.elevation_deg for tg in targets])
        amp = noise_lsb * 10 ** (np.array([tg.snr_db for tg in targets]) / 20.0)
        ux, uz = np.sin(az) * np.cos(el), np.sin(el)
        # exp(2 pi i (R0 + v t_c) f_n) = exp(2 pi i R0 f_n) exp(2 pi i v t_c f_n): the fast-time
        # term per target, the slow-time term once per distinct velocity
        fast = amp[:, None] * _cis(np.outer(rng_m, freq_n))  # (K, N)
        ang = -0.5 * (ux[:, None, None] * pos[None, ..., 0] + uz[:, None, None] * pos[None, ..., 1])
        space = _cis(ang)  # (K, T, R)
        fast = fast.astype(np.complex64)
        vs, group = np.unique(vel, return_inverse=True)
        for g, v in enumerate(vs):
            sel = group == g
            summed = np.einsum("ktr,kn->trn", space[sel], fast[sel])  # (BLAS matmul: slower)
            slow = _cis(v * t_c.reshape(L, T)[..., None] * freq_n)  # (L, T, N)
            cube += slow[:, :, None, :] * summed[None]
    cube = cube.reshape(L * T, R, N)
    flat = cube.view(np.float32)  # I, Q interleaved
    if noise_lsb > 0:
        flat += (noise_lsb / math.sqrt(2.0)) * rng.standard_normal(flat.shape, dtype=np.float32)
    if quantise:
        np.clip(np.rint(flat, out=flat), -32768, 32767, out=flat)
    return cube.reshape(L, T * R, N)


def _cis(cycles: np.ndarray) -> np.ndarray:
    """exp(2 pi i cycles) as complex64 (whole cycles removed in float64 first, so a phase of
    thousands of cycles keeps its sub-cycle precision)."""
    frac = (2.0 * np.pi * (cycles - np.floor(cycles))).astype(np.float32)
    out = np.empty(frac.shape, dtype=np.complex64)
    out.real = np.cos(frac)
    out.imag = np.sin(frac)
    return out


def synth_raw_frames(
    chirp,
    geom: FrameGeometry,
    targets: list[Target],
    num_frames: int,
    layout: AntennaLayout = AWR2243BOOST,
    noise_lsb: float = 4.0,
    seed: int = 0,
) -> bytes:
    """`num_frames` consecutive raw frames in the geometry's LVDS layout (as a DCA1000 capture)."""
    rng = np.random.default_rng(seed)
    return b"".join(
        cube_to_raw(synth_cube(chirp, geom, targets, layout, noise_lsb, i, rng), geom)
        for i in range(num_frames)
    )
