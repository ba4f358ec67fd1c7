"""Angle measurement errors of a TI-class MIMO radar, per point (pure numpy).

What a detection's azimuth and elevation are off by, from four causes:

1. **Array noise** (Cramér-Rao bound of the virtual array). The DSP estimates the spatial
   frequency of a horizontal row of `channels_az` virtual channels lambda/2 apart (FFT peak,
   which reaches the bound at the SNRs a CFAR passes). For a single source in white noise
   (Rife & Boorstyn 1974) the phase step w = pi u_x per channel has

       var(w) = 6 / (s N (N^2 - 1)),   N = channels_az,

   with s the per-channel SNR of the range-Doppler cell. The point's SNR as our DSP reports it
   (drivers/dca1000/dsp.py: power summed over channels over the CFAR noise estimate) is
   `snr_db = 10 log10(1 + s)`, so s = 10^(snr_db / 10) - 1. Azimuth az = atan2(x, y) with
   u_x = sin(az) cos(el), hence

       sigma_az = sqrt(6 / (s N (N^2 - 1))) / (pi cos(az) cos(el))          (rad)

   growing as 1/cos(az) off boresight. Elevation comes, as in TI's mmw demo and our DSP, from
   the phase between the sum of the `channels_el` channels of the raised row (`row_offset`
   half-wavelengths up) and the sum of the azimuth row, both steered to the azimuth found:

       sigma_el = sqrt((1/channels_el + 1/channels_az) / (2 s)) / (pi row_offset cos(el))

   (the rows' horizontal centroids coincide on the TI boards, so azimuth errors do not leak in).
   An array with `channels_el = 0` measures no elevation: the point is reported at el = 0.

2. **Glint** of extended targets. Several scatterers of one vehicle share a range-Doppler cell;
   the array sees their coherent sum, whose apparent direction is, for an extent well inside
   the beam, the phase-front centroid

       e = Re(sum_k b_k u_k / sum_k b_k)

   (b_k complex amplitudes with random phases, u_k the scatterers' angle offsets from the centre
   of the target's angular extent). It mostly stays within the extent (median about 0.2 x the
   extent, p90 about 0.5 x), and leaves it in fades, when the scatterers nearly cancel.

3. **Their interplay**, and the estimator itself, are not left to formulas: `draw_angle_errors`
   simulates each point's array snapshot — `glint_scatterers` scatterers (exponential powers,
   uniform phases) spread uniformly over `glint_factor` x the point's angular extent, scaled to
   the per-channel SNR s, plus white noise — and estimates azimuth (FFT peak of the azimuth row)
   and elevation (phase between the steered rows) as the DSP does. A point target's errors then
   follow the bounds above, a vehicle's the glint, and a faded vehicle's the larger noise of a
   distorted wavefront. The reported SNR already contains the fade; as long as targets' mean
   SNRs spread widely (as range makes them), the fade given the reported SNR is distributed as
   without conditioning, so the snapshot is scaled to the reported SNR whatever its scatterers.

4. **Calibration residual**: a per-radar bias (`calib_bias_*_deg`, constant for one radar: draw
   a spec per radar, not per scene) plus a per-point Gaussian floor (`calib_floor_*_deg`) for what
   varies with angle and temperature (residual channel phase errors, mutual coupling). The
   defaults are 0: an ideally calibrated array, as our synthesiser's; a TI board calibrated once
   on a corner reflector keeps some tenths of a degree (see ANGLE_SPEC_RANGES).

Frames and units: radar frame (x right, y forward, z up), az = atan2(x, y), el = asin(z / r);
angles in radians unless a name ends in `_deg`; SNR in dB as defined above.

Grounding: `mmatch dsp --angle-study` synthesises raw ADC frames of point targets and of
vehicles (2-5 scatterers per range-Doppler cell) with drivers/dca1000/synth.py, runs our DSP and
prints, per band of the reported SNR, the measured median / p90 errors next to this model's;
tests/dca1000/test_angle_model.py holds them within 20 % (5-45 dB; above, the DSP's reported
SNR saturates and the study's strongest vehicles are seldom faded, so the model overstates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import lru_cache

import numpy as np

from mmatch.errors import ConfigError

ArrayLike = np.ndarray | float


@dataclass(frozen=True)
class AngleErrorSpec:
    """Constants of the angle error model (defaults: AWR2243/xWR18xx BOOST, 3 TX x 4 RX).

    channels_az: virtual channels of the horizontal row (lambda/2 apart) that give azimuth.
    channels_el: virtual channels of the raised row that give elevation (0 = no elevation).
    row_offset: height of that row above the azimuth row, in half-wavelengths.
    glint_factor: the scatterers spread over this many times the extent the caller gives
        (1 = as given; glint scales with it).
    glint_scatterers: (min, max) scatterers per range-Doppler cell of an extended target.
    calib_bias_az_deg / calib_bias_el_deg: per-radar constant offset, deg.
    calib_floor_az_deg / calib_floor_el_deg: per-point Gaussian residual sigma, deg.
    min_snr_db: SNRs below this are taken as this (a CFAR passes nothing weaker).
    """

    channels_az: int = 8
    channels_el: int = 4
    row_offset: float = 1.0
    glint_factor: float = 1.0
    glint_scatterers: tuple[int, int] = (2, 5)
    calib_bias_az_deg: float = 0.0
    calib_bias_el_deg: float = 0.0
    calib_floor_az_deg: float = 0.0
    calib_floor_el_deg: float = 0.0
    min_snr_db: float = 1.0

    def __post_init__(self) -> None:
        if self.channels_az < 2:
            raise ConfigError(f"channels_az must be >= 2, got {self.channels_az}")
        if self.channels_el < 0:
            raise ConfigError(f"channels_el must be >= 0, got {self.channels_el}")
        lo, hi = self.glint_scatterers
        if not 1 <= lo <= hi:
            raise ConfigError(
                f"glint_scatterers must be 1 <= min <= max, got {self.glint_scatterers}"
            )
        if not (math.isfinite(self.row_offset) and self.row_offset > 0):
            raise ConfigError(f"row_offset must be finite and > 0, got {self.row_offset}")
        for name in ("glint_factor", "calib_floor_az_deg", "calib_floor_el_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be finite and >= 0, got {v}")
        for name in ("calib_bias_az_deg", "calib_bias_el_deg", "min_snr_db"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ConfigError(f"{name} must be finite, got {v}")


ANGLE_SPEC_RANGES: dict[str, tuple[float, float]] = {
    "channels_az": (8, 12),
    "channels_el": (2, 4),
    "glint_factor": (0.8, 1.3),
    "calib_bias_az_deg": (-0.5, 0.5),
    "calib_bias_el_deg": (-1.0, 1.0),
    "calib_floor_az_deg": (0.1, 0.5),
    "calib_floor_el_deg": (0.2, 1.0),
}
"""Range of each constant a deployment cannot know, for `draw_angle_spec` (`--physics wide`):
8-12 azimuth channels (xWR16xx/18xx/AWR2243 BOOST to cascaded-lite arrays), 2-4 elevation
channels, glint within -20/+30 % of the scatterer physics, a calibration bias of up to
0.5 deg in azimuth and 1 deg in elevation (TI's one-shot corner-reflector calibration) and a
floor of 0.1-0.5 deg azimuth, 0.2-1 deg elevation."""


def draw_angle_spec(
    rng: np.random.Generator,
    ranges: dict[str, tuple[float, float]] = ANGLE_SPEC_RANGES,
    base: AngleErrorSpec = AngleErrorSpec(),
) -> AngleErrorSpec:
    """An AngleErrorSpec with each field of `ranges` drawn uniformly from its (lo, hi) range
    (integers for the channel counts); the other fields come from `base`. A key that is no
    field, or a range that is empty or not finite, is refused naming the key."""
    names = {f.name: f for f in fields(AngleErrorSpec)}
    kw: dict = {}
    for key, rg in ranges.items():
        if key not in names or key == "glint_scatterers":
            raise ConfigError(f"angle error range {key!r}: no such constant")
        try:
            lo, hi = float(rg[0]), float(rg[1])
        except (TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f"angle error range {key!r}: want (lo, hi), got {rg!r}") from exc
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
            raise ConfigError(f"angle error range {key!r}: ({lo}, {hi}) is empty or not finite")
        if key.startswith("channels_"):
            if math.ceil(lo) > hi:
                raise ConfigError(f"angle error range {key!r}: ({lo}, {hi}) holds no whole number")
            kw[key] = int(rng.integers(math.ceil(lo), math.floor(hi) + 1))
        else:
            kw[key] = float(rng.uniform(lo, hi))
    try:
        return base.__class__(**{**{f: getattr(base, f) for f in names}, **kw})
    except ConfigError as exc:
        raise ConfigError(f"angle error ranges give an impossible constant: {exc}") from exc


def channel_snr(snr_db: ArrayLike, spec: AngleErrorSpec = AngleErrorSpec()) -> np.ndarray:
    """Per-channel SNR s (linear) of a point whose reported SNR is snr_db: 10^(snr/10) - 1."""
    snr = np.maximum(np.asarray(snr_db, dtype=np.float64), spec.min_snr_db)
    return np.expm1(snr * (math.log(10.0) / 10.0))


def noise_sigma(
    snr_db: ArrayLike,
    az_rad: ArrayLike,
    el_rad: ArrayLike = 0.0,
    spec: AngleErrorSpec = AngleErrorSpec(),
) -> tuple[np.ndarray, np.ndarray]:
    """(sigma_az, sigma_el) in rad of the array-noise term (Cramér-Rao, formulas above).

    sigma_el is 0 for an array without elevation channels (the error is then -el, see
    `draw_angle_errors`). Inputs broadcast; |az| and |el| are capped at 80 deg."""
    s = channel_snr(snr_db, spec)
    cap = math.radians(80.0)
    cos_az = np.cos(np.minimum(np.abs(np.asarray(az_rad, dtype=np.float64)), cap))
    cos_el = np.cos(np.minimum(np.abs(np.asarray(el_rad, dtype=np.float64)), cap))
    n = spec.channels_az
    s_az = np.sqrt(6.0 / (s * n * (n * n - 1.0))) / (math.pi * cos_az * cos_el)
    if spec.channels_el:
        var = (1.0 / spec.channels_el + 1.0 / n) / (2.0 * s)
        s_el = np.sqrt(var) / (math.pi * spec.row_offset * cos_el)
    else:
        s_el = np.zeros_like(s)
    s_az, s_el = np.broadcast_arrays(s_az, s_el)
    return s_az.copy(), s_el.copy()


@lru_cache(maxsize=16)
def glint_scale(lo: int, hi: int) -> float:
    """Gaussian-equivalent sigma of the glint per unit extent (median |e| / 0.6745 of the
    phase-front centroid of lo..hi random scatterers over a unit extent; seeded Monte Carlo)."""
    rng = np.random.default_rng(0)
    n = 40000
    k = rng.integers(lo, hi + 1, n)
    alive = np.arange(hi)[None, :] < k[:, None]
    b = np.sqrt(rng.exponential(1.0, (n, hi))) * alive * np.exp(2j * np.pi * rng.random((n, hi)))
    u = rng.uniform(-0.5, 0.5, (n, hi))
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.real((b * u).sum(axis=1) / b.sum(axis=1))
    return float(np.nanmedian(np.abs(e)) / 0.6745)


def angle_sigma(
    snr_db: ArrayLike,
    az_rad: ArrayLike,
    el_rad: ArrayLike = 0.0,
    extent_az_rad: ArrayLike = 0.0,
    extent_el_rad: ArrayLike = 0.0,
    spec: AngleErrorSpec = AngleErrorSpec(),
) -> tuple[np.ndarray, np.ndarray]:
    """(sigma_az, sigma_el) in rad: a Gaussian-equivalent scale of a point's angle error, for
    gates and wedges. sqrt(noise^2 + (g * glint_factor * extent)^2 + floor^2), with the noise
    of `noise_sigma` and g = `glint_scale` (about 0.29: a 2 m car face at 30 m, 3.8 deg wide,
    glints by about 1.1 deg). The calibration bias is a constant, not in sigma. The drawn errors
    have heavier tails than a Gaussian of this sigma (fades); sigma_el is 0 without elevation."""
    s_az, s_el = noise_sigma(snr_db, az_rad, el_rad, spec)
    g = glint_scale(*spec.glint_scatterers) * spec.glint_factor
    ga = g * np.abs(np.asarray(extent_az_rad, dtype=np.float64))
    ge = g * np.abs(np.asarray(extent_el_rad, dtype=np.float64))
    fa, fe = math.radians(spec.calib_floor_az_deg), math.radians(spec.calib_floor_el_deg)
    sig_az = np.sqrt(s_az**2 + ga**2 + fa**2)
    sig_el = np.sqrt(s_el**2 + ge**2 + fe**2) if spec.channels_el else np.zeros_like(sig_az)
    sig_az, sig_el = np.broadcast_arrays(sig_az, sig_el)
    return sig_az.copy(), sig_el.copy()


def _array(spec: AngleErrorSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Virtual channel positions (x, z) in lambda/2 of the model array, and the azimuth-row mask:
    the azimuth row on x = 0..N-1 centred, the elevation row over its middle, row_offset up."""
    n, m = spec.channels_az, spec.channels_el
    x = np.concatenate([np.arange(n) - (n - 1) / 2.0, np.arange(m) - (m - 1) / 2.0])
    z = np.concatenate([np.zeros(n), np.full(m, spec.row_offset)])
    return x, z, np.arange(n + m) < n


def _peak_u(y: np.ndarray, x: np.ndarray, n_fft: int) -> np.ndarray:
    """u maximising |sum_n y_n exp(i pi x_n u)| (the FFT peak of the row, as the DSP finds it),
    refined by Newton steps on the exact array factor. y: (K, N) snapshots, x: (N,)."""
    spectrum = np.abs(np.fft.ifft(y, n=n_fft, axis=1))  # exp(+i 2 pi k n / n_fft): u = 2 k / n_fft
    k = np.argmax(spectrum, axis=1)
    u = 2.0 * k / n_fft
    u = np.where(u >= 1.0, u - 2.0, u)
    # the row starts at x[0], not 0: the FFT phase reference only shifts the spectrum's phase
    px = np.pi * x[None, :]
    for _ in range(3):
        e = np.exp(1j * px * u[:, None])
        a0 = (y * e).sum(axis=1)
        a1 = (y * e * (1j * px)).sum(axis=1)
        a2 = (y * e * -(px**2)).sum(axis=1)
        g = 2.0 * np.real(np.conj(a0) * a1)
        h = 2.0 * (np.abs(a1) ** 2 + np.real(np.conj(a0) * a2))
        step = np.where(h < 0, -g / np.where(h < 0, h, -1.0), 0.0)
        u = u + np.clip(step, -1.0 / len(x), 1.0 / len(x))
    return u


def draw_glint_and_noise(
    rng: np.random.Generator,
    snr_db: np.ndarray,
    az_rad: np.ndarray,
    el_rad: np.ndarray,
    extent_az_rad: np.ndarray,
    extent_el_rad: np.ndarray,
    spec: AngleErrorSpec = AngleErrorSpec(),
    chunk: int = 20000,
) -> tuple[np.ndarray, np.ndarray]:
    """Array-noise plus glint errors (rad), by simulating each point's array snapshot.

    Per point: `glint_scatterers` scatterers (exponential powers, uniform phases) spread uniformly
    over the point's angular extent (none: a single direction), their sum over the virtual array
    (phase -pi (x u_x + z u_z), antenna.py convention) scaled to the per-channel SNR s of the
    reported SNR, plus unit complex white noise per channel; azimuth from the FFT peak of the
    azimuth row (Newton-refined), elevation from the phase between the steered rows, as the DSP
    does. A point target's error then follows the Cramér-Rao bound (`noise_sigma`) and a vehicle's
    the phase-front glint; their interplay in fades comes out too. Inputs: 1-D arrays."""
    x, z, az_row = _array(spec)
    n_az = spec.channels_az
    n_fft = 8 * (1 << (n_az - 1).bit_length())
    lo, hi = spec.glint_scatterers
    d_az = np.empty(len(snr_db))
    d_el = np.empty(len(snr_db))
    for s0 in range(0, len(snr_db), chunk):
        sl = slice(s0, s0 + chunk)
        az, el = az_rad[sl], el_rad[sl]
        n = len(az)
        k = rng.integers(lo, hi + 1, n)
        alive = np.arange(hi)[None, :] < k[:, None]
        phase = np.exp(2j * np.pi * rng.random((n, hi)))
        b = np.sqrt(rng.exponential(1.0, (n, hi))) * alive * phase
        spread = spec.glint_factor * rng.uniform(-0.5, 0.5, (2, n, hi))
        saz = az[:, None] + extent_az_rad[sl, None] * spread[0]
        sel = el[:, None] + extent_el_rad[sl, None] * spread[1]
        ux = np.sin(saz) * np.cos(sel)
        uz = np.sin(sel)
        phase = -np.pi * (ux[:, :, None] * x[None, None, :] + uz[:, :, None] * z[None, None, :])
        y = np.einsum("kh,khn->kn", b, np.exp(1j * phase))  # (n, channels)
        power = np.mean(np.abs(y) ** 2, axis=1)
        scale = np.sqrt(channel_snr(snr_db[sl], spec) / np.maximum(power, 1e-30))
        y = y * scale[:, None]
        y += np.sqrt(0.5) * (rng.standard_normal(y.shape) + 1j * rng.standard_normal(y.shape))
        ya = y[:, az_row]
        ux_hat = np.clip(_peak_u(ya, x[az_row], n_fft), -1.0, 1.0)
        if spec.channels_el:
            w = y * np.exp(1j * np.pi * ux_hat[:, None] * x[None, :])
            e = w[:, ~az_row].sum(axis=1)
            a = w[:, az_row].sum(axis=1)
            uz_hat = np.clip(-np.angle(e * np.conj(a)) / (np.pi * spec.row_offset), -1.0, 1.0)
        else:
            uz_hat = np.zeros(n)
        norm = np.hypot(ux_hat, uz_hat)
        shrink = np.where(norm > 1.0, 1.0 / np.maximum(norm, 1e-12), 1.0)
        ux_hat, uz_hat = ux_hat * shrink, uz_hat * shrink
        uy_hat = np.sqrt(np.maximum(0.0, 1.0 - ux_hat**2 - uz_hat**2))
        d_az[sl] = np.arctan2(ux_hat, uy_hat) - az
        d_el[sl] = np.arcsin(uz_hat) - el
    return d_az, d_el


def draw_angle_errors(
    rng: np.random.Generator,
    snr_db: ArrayLike,
    az_rad: ArrayLike,
    el_rad: ArrayLike,
    extent_az_rad: ArrayLike = 0.0,
    extent_el_rad: ArrayLike = 0.0,
    spec: AngleErrorSpec = AngleErrorSpec(),
) -> tuple[np.ndarray, np.ndarray]:
    """(d_az, d_el) in rad to add to each point's true azimuth and elevation.

    snr_db: the point's reported SNR (dB, as our DSP and TI's side info give it); az_rad, el_rad:
    the true direction (radar frame); extent_az_rad / extent_el_rad: the angular width / height
    of the part of the target that shares the point's range-Doppler cell (0 for point-like
    targets, e.g. w / r for a face w metres wide at r metres). Arrays broadcast to one shape.
    Array noise and glint come from `draw_glint_and_noise`, then the calibration bias and floor.
    """
    snr, az, el, ea, ee = np.broadcast_arrays(
        *(
            np.asarray(a, dtype=np.float64)
            for a in (snr_db, az_rad, el_rad, extent_az_rad, extent_el_rad)
        )
    )
    shape = snr.shape
    d_az, d_el = draw_glint_and_noise(
        rng, snr.ravel(), az.ravel(), el.ravel(), np.abs(ea.ravel()), np.abs(ee.ravel()), spec
    )
    d_az, d_el = d_az.reshape(shape), d_el.reshape(shape)
    d_az += math.radians(spec.calib_bias_az_deg)
    if spec.calib_floor_az_deg:
        d_az += math.radians(spec.calib_floor_az_deg) * rng.standard_normal(shape)
    if spec.channels_el:
        d_el += math.radians(spec.calib_bias_el_deg)
        if spec.calib_floor_el_deg:
            d_el += math.radians(spec.calib_floor_el_deg) * rng.standard_normal(shape)
    return d_az, d_el


__all__ = [
    "ANGLE_SPEC_RANGES",
    "AngleErrorSpec",
    "channel_snr",
    "draw_angle_errors",
    "draw_angle_spec",
    "angle_sigma",
    "draw_glint_and_noise",
    "glint_scale",
    "noise_sigma",
]
