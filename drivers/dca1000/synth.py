"""FMCW raw-ADC synthesiser: point targets -> complex int16 cube / raw LVDS frames.

Model (complex baseband, TI complex1x: a target appears at a positive beat frequency):
for chirp c (frame order; loop l = c // T, slot k = c % T, TX = tx_order[k]) starting at
t_c = c * Tc (Tc = idle + ramp end time), ADC sample n at t_n = adcStart + n / fs after the ramp
start, and virtual channel position p (lambda/2 units, see antenna.py),

    phase = 2 pi (f0 + S t_n) * 2 R(t_c) / c  -  pi (p . u)        R(t_c) = R0 + v t_c

so the range grows with v > 0 (Doppler positive = range increasing, DESIGN.md) and a target to
the right (u_x > 0) lags on antennas further right. Intra-chirp motion is neglected.
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
    cube = np.zeros((L * T, R, N), dtype=np.complex128)
    freq_n = 2.0 * (f0 + s_hz * t_n) / C  # cycles per metre
    for tg in targets:
        az, el = math.radians(tg.azimuth_deg), math.radians(tg.elevation_deg)
        ux, uz = math.sin(az) * math.cos(el), math.sin(el)
        amp = noise_lsb * 10 ** (tg.snr_db / 20.0)
        r_c = tg.range_m + tg.velocity_mps * t_c  # (C,)
        slot = np.arange(L * T) % T
        ang = -0.5 * (pos[..., 0] * ux + pos[..., 1] * uz)  # (T, R) cycles
        cycles = r_c[:, None, None] * freq_n[None, None, :] + ang[slot][:, :, None]
        cycles -= np.floor(cycles)
        cube += amp * np.exp(2j * np.pi * cycles)
    if noise_lsb > 0:
        sigma = noise_lsb / math.sqrt(2.0)
        cube += sigma * (rng.standard_normal(cube.shape) + 1j * rng.standard_normal(cube.shape))
    if quantise:
        cube = np.clip(np.rint(cube.real), -32768, 32767) + 1j * np.clip(
            np.rint(cube.imag), -32768, 32767
        )
    return cube.reshape(L, T * R, N).astype(np.complex64)


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
