"""Radar signal processing of a raw ADC cube into a point cloud (vectorised numpy/scipy).

Chain (per frame): range FFT with window -> optional static clutter removal (subtract the
window-weighted mean over chirps) -> Doppler FFT with window -> non-coherent sum over virtual
channels -> 2D CFAR (CA over the ring or its smaller / greater range half as cfarCfg averageMode
says, or OS) with peak grouping (local maximum in 3 x 3 cells, Doppler cyclic; a cell whose
channel vector points elsewhere than its stronger neighbour's is a target of its own, one that
matches a far stronger cell's in its CFAR window a sidelobe) -> per detection: TDM-MIMO Doppler
phase compensation (sub-bin Doppler), channel phase calibration,
azimuth FFT over the horizontal virtual array, elevation from the raised channels -> points
x, y, z, doppler, snr.

Frames: radar frame x right, y forward, z up (m); doppler m/s, positive = range increasing;
snr dB over the CFAR noise estimate. Antenna phase model: see antenna.py.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft
from scipy import ndimage
from scipy.signal import get_window

from mmatch.errors import ConfigError
from mmatch.types import empty_points

from .antenna import AWR2243BOOST, AntennaLayout
from .layout import FrameGeometry

log = logging.getLogger(__name__)

_GROUP_MARGIN = 2.0
"""A cell beside a stronger one is its own target only if every neighbour, projected on the
cell's channel vector, is at least this factor (3 dB) weaker (a strong target half a bin off the
grid spreads evenly over 2 x 2 cells: those are one target)."""

_SIDELOBE_RATIO = 10 ** (25 / 10)
"""A detection is a sidelobe of a cell in its CFAR window's range row or Doppler column whose
power along the detection's channel vector is more than this (25 dB; Hann sidelobes are 31 dB
down) above the detection's."""

_NB = np.array([(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b])
_NB_D, _NB_R = _NB[:, 0], _NB[:, 1]  # the 8 neighbours (Doppler, range offsets)


AVERAGE_MODES = ("ca", "cago", "caso")
"""CA-CFAR averaging by cfarCfg averageMode 0, 1, 2."""


@dataclass(frozen=True)
class DspConfig:
    """Processing settings (defaults are TI's mmw demo values; `from_cfg` reads a .cfg).

    guard/train: CFAR guard and training cells on each side, (range, doppler).
    threshold_db: a cell is detected when its power exceeds the noise estimate by this much;
        the noise estimate is the training-cell mean (CA) or the `os_rank` quantile (OS).
    average: how CA combines the training ring's nearer-range and farther-range halves (cfarCfg
        averageMode of the range direction): "ca" the whole ring, "cago" the greater half, "caso"
        the smaller half (TI's vehicle cfgs: a strong target on one side in range, e.g. a nearer
        roadside post in the same Doppler bin, then does not mask a weaker one).
    peak_grouping: keep only cells that are the local maximum of their 3 x 3 neighbourhood; with
        `signature_grouping`, a cell that is not is still kept when its neighbours, projected on
        its own channel vector, are all at least 3 dB weaker (a target at another angle beside a
        stronger one, not the stronger one's leakage), and a cell is dropped when a cell of its
        CFAR window's range row or Doppler column is 25 dB stronger along its channel vector (a
        Hann sidelobe of that cell). See RadarDsp._local_max.
    min_range_m / max_range_m: detections outside are ignored (None = the cfg's max range).
    angle_fft: azimuth FFT size; max_points: keep the strongest points of a frame.
    range_bias_m, channel_phase: calibration of compRangeBiasAndRxChanPhase (channel_phase:
        complex factor per virtual channel in cube order, multiplied in).
    tdm_compensation: remove the Doppler phase of later TX slots (off only to show why it matters).
    multi_obj_threshold: when set (cfg multiObjBeamForming), a second azimuth peak outside the
        main lobe whose magnitude is at least this fraction of the first gives a second point in
        the same range-Doppler cell (two cars side by side at the same range and speed).
    """

    window: str = "hann"
    clutter_removal: bool = False
    cfar: str = "ca"
    average: str = "ca"
    guard: tuple[int, int] = (4, 2)
    train: tuple[int, int] = (8, 4)
    threshold_db: float = 15.0
    os_rank: float = 0.75
    peak_grouping: bool = True
    signature_grouping: bool = True
    min_range_m: float = 0.3
    max_range_m: float | None = None
    angle_fft: int = 256
    elevation: bool = True
    max_points: int = 1024
    range_bias_m: float = 0.0
    channel_phase: tuple[complex, ...] | None = None
    tdm_compensation: bool = True
    multi_obj_threshold: float | None = None

    def __post_init__(self) -> None:
        if self.cfar not in ("ca", "os"):
            raise ConfigError(f"cfar must be 'ca' or 'os', got {self.cfar!r}")
        if self.average not in AVERAGE_MODES:
            raise ConfigError(f"average must be one of {AVERAGE_MODES}, got {self.average!r}")
        if not 0 < self.os_rank < 1:
            raise ConfigError("os_rank must be in (0, 1)")
        if min(self.guard) < 0 or min(self.train) < 1:
            raise ConfigError("CFAR guard must be >= 0 and training >= 1 cell")

    @classmethod
    def from_cfg(cls, cfg, **overrides) -> "DspConfig":
        """Read cfarCfg (range = procDirection 0, Doppler = 1), clutterRemoval, cfarFovCfg
        (range limits) and compRangeBiasAndRxChanPhase from a drivers.ti.cfg.RadarCfg."""
        kw: dict = {}
        guard = list(cls.guard)
        train = list(cls.train)
        for lineno, cmd, args in cfg.commands:
            try:
                a = [float(x) for x in args]
            except ValueError as exc:
                raise ConfigError(f"{cfg.path}:{lineno}: {cmd}: {exc}") from exc
            if cmd == "cfarCfg" and len(a) in (8, 9):
                if len(a) == 9:
                    a = a[1:]  # drop subFrameIdx (SDK 3.x)
                direction, mode, win, grd, thr = int(a[0]), int(a[1]), int(a[2]), int(a[3]), a[6]
                if direction in (0, 1):
                    train[direction], guard[direction] = max(1, win), max(0, grd)
                    if direction == 0:
                        kw["threshold_db"] = thr
                        if not 0 <= mode < len(AVERAGE_MODES):
                            raise ConfigError(
                                f"{cfg.path}:{lineno}: cfarCfg averageMode {mode}: want 0 (CA), "
                                "1 (CAGO) or 2 (CASO)"
                            )
                        kw["average"] = AVERAGE_MODES[mode]
                    kw["peak_grouping"] = bool(a[7])
            elif cmd == "multiObjBeamForming" and len(a) in (2, 3):
                enabled, thr = a[-2], a[-1]
                kw["multi_obj_threshold"] = thr if enabled else None
            elif cmd == "clutterRemoval":
                kw["clutter_removal"] = bool(a[-1])
            elif cmd == "cfarFovCfg" and len(a) == 4 and int(a[1]) == 0:
                kw["min_range_m"], kw["max_range_m"] = a[2], a[3]
            elif cmd == "compRangeBiasAndRxChanPhase":
                kw["range_bias_m"] = a[0]
                re, im = np.asarray(a[1::2]), np.asarray(a[2::2])
                kw["channel_phase"] = tuple(complex(x, y) for x, y in zip(re, im, strict=False))
        kw["guard"], kw["train"] = tuple(guard), tuple(train)
        kw.update(overrides)
        return cls(**kw)


@dataclass(frozen=True)
class DspResult:
    """Points and the intermediate maps of one frame.

    points: float32 (K, 5) x, y, z, doppler, snr. cells: int (K, 2) (doppler bin, range bin)
    of each point (Doppler bin unshifted, 0..D-1). power: float32 (D, R) detection map (None
    unless asked for). noise: float32 (D, R) CA noise map (None unless asked for).
    """

    points: np.ndarray
    cells: np.ndarray
    power: np.ndarray | None = None
    noise: np.ndarray | None = None


class RadarDsp:
    """Point-cloud processing for one chirp configuration.

    chirp: drivers.ti.cfg.ChirpParams; geom: FrameGeometry (tx order, RX); layout: antenna
    positions. Precomputes windows and steering maps; `process(cube)` is then allocation-light.
    """

    def __init__(
        self,
        chirp,
        geom: FrameGeometry,
        config: DspConfig | None = None,
        layout: AntennaLayout = AWR2243BOOST,
    ) -> None:
        self.chirp = chirp
        self.geom = geom
        config = config if config is not None else DspConfig()
        self.config = config
        self.L = geom.num_loops
        self.T = len(geom.tx_order)
        self.V = geom.num_virtual
        self.N = geom.num_samples
        self.NR = max(chirp.num_range_bins, self.N)
        self.range_step = chirp.range_idx_to_m * chirp.num_range_bins / self.NR
        self.doppler_step = chirp.doppler_resolution_mps * chirp.num_doppler_bins / self.L
        self.win_r = get_window(config.window, self.N, fftbins=False).astype(np.float32)
        self.win_d = get_window(config.window, self.L, fftbins=False).astype(np.float32)
        # the window's coherent gain is divided out so power stays in ADC units
        self.win_r /= self.win_r.mean()
        self.win_d /= self.win_d.mean()
        self.win_rd = self.win_d[:, None, None] * self.win_r[None, None, :]  # (L, 1, N)
        max_r = config.max_range_m if config.max_range_m is not None else chirp.max_range_m
        self.r_lo = max(
            1, int(math.ceil((config.min_range_m + config.range_bias_m) / self.range_step))
        )
        self.r_hi = min(self.NR, int(max_r / self.range_step) + 1)
        if self.r_lo >= self.r_hi:
            raise ConfigError(f"range limits {config.min_range_m}..{max_r} m leave no range bin")
        # signed Doppler bin of each unshifted bin, and the TDM-MIMO slot of each virtual channel
        self.d_signed = np.fft.fftfreq(self.L, 1.0 / self.L).astype(np.int64)
        self.slot = np.repeat(np.arange(self.T), geom.num_rx)
        if config.channel_phase is not None:
            if len(config.channel_phase) < self.V:
                raise ConfigError(
                    f"channel phase calibration has {len(config.channel_phase)} values, "
                    f"{self.V} virtual channels need one each"
                )
            self.cal = np.asarray(config.channel_phase[: self.V], dtype=np.complex64)
        else:
            self.cal = None
        # virtual array geometry
        pos = layout.virtual_positions(geom.tx_order, geom.rx)
        self.pos = pos
        zs, counts = np.unique(pos[:, 1], return_counts=True)
        z_az = zs[np.argmax(counts)]
        self.az_idx = np.flatnonzero(pos[:, 1] == z_az)
        xa = pos[self.az_idx, 0]
        x0 = xa.min()
        if not np.allclose(xa - x0, np.round(xa - x0)):
            raise ConfigError(
                f"layout {layout.name}: azimuth positions {xa} are not on a lambda/2 grid"
            )
        slots = np.round(xa - x0).astype(int)
        self.n_az = int(slots.max()) + 1
        m = np.zeros((len(self.az_idx), self.n_az), dtype=np.complex64)
        m[np.arange(len(slots)), slots] = 1.0
        m /= np.maximum(m.sum(axis=0, keepdims=True).real, 1)
        self.az_map = m
        self.el_idx = np.flatnonzero(pos[:, 1] != z_az)
        if len(self.el_idx):
            dz = pos[self.el_idx, 1] - z_az
            self.el_dz = float(dz[0])
            if not np.allclose(dz, self.el_dz) or abs(self.el_dz) > 1.0 + 1e-9:
                raise ConfigError(
                    f"layout {layout.name}: elevation channels need one row within lambda/2"
                )
        self.n_fft_az = max(config.angle_fft, 1 << (self.n_az - 1).bit_length())
        # CFAR training ring (offsets) for OS and for the ring size in CA
        gr, gd = config.guard
        tr, td = config.train
        dd, dr = np.meshgrid(
            np.arange(-(gd + td), gd + td + 1), np.arange(-(gr + tr), gr + tr + 1), indexing="ij"
        )
        ring = (np.abs(dd) > gd) | (np.abs(dr) > gr)
        self.ring_d = dd[ring]
        self.ring_r = dr[ring]
        self.outer = (2 * (gd + td) + 1, 2 * (gr + tr) + 1)
        self.inner = (2 * gd + 1, 2 * gr + 1)
        self.half_cells = self.outer[0] * (gr + tr + 1) - self.inner[0] * (gr + 1)
        # the CFAR window's range row and Doppler column beyond the 3 x 3 block (sidelobe test)
        wr = np.array([o for o in range(-(gr + tr), gr + tr + 1) if abs(o) > 1])
        wd = np.array([o for o in range(-(gd + td), gd + td + 1) if abs(o) > 1])
        self.cross_d = np.concatenate([np.zeros(len(wr), int), wd])
        self.cross_r = np.concatenate([wr, np.zeros(len(wd), int)])
        self.thr = 10 ** (config.threshold_db / 10)
        self.os_k = int(config.os_rank * (len(self.ring_d) - 1))

    # ---------------------------------------------------------------------------------------------
    def range_doppler(self, cube: np.ndarray) -> np.ndarray:
        """complex64 (D, V, R) range-Doppler spectra of a (loops, virtual, samples) cube."""
        if cube.shape != (self.L, self.V, self.N):
            raise ConfigError(
                f"cube shape {cube.shape} does not match the cfg {(self.L, self.V, self.N)}"
            )
        # both windows in one pass (they commute with the range FFT)
        x = cube * self.win_rd
        x = sfft.fft(x, n=self.NR, axis=2, workers=1, overwrite_x=True)
        if self.config.clutter_removal:
            # subtract the Doppler-window-weighted mean over chirps (times the window, which is
            # already on): it zeroes Doppler bin 0 exactly, and a moving target's (Hann-sidelobe-
            # small) share of it is negligible, whereas the plain mean leaves a -30 dB ghost of
            # every moving target at Doppler 0
            m = x.sum(axis=0) / self.win_d.sum()
            x -= m[None] * self.win_d[:, None, None]
        return sfft.fft(x, axis=0, workers=1, overwrite_x=True)

    def detection_map(self, spec: np.ndarray) -> np.ndarray:
        """float32 (D, R) power summed over virtual channels."""
        f = spec.view(np.float32)
        p = np.einsum("dvr,dvr->dr", f, f)
        return p[:, 0::2] + p[:, 1::2]

    def ca_noise(self, power: np.ndarray) -> np.ndarray:
        """CA-CFAR noise (Doppler cyclic, range edges replicated): mean of the training ring around
        every cell ("ca"), or the greater / smaller ("cago" / "caso") of the means of its
        nearer-range half (range offsets -(guard+train)..0) and farther-range half (0..+)."""
        mode = ("wrap", "nearest")
        (od, orr), (idd, ir) = self.outer, self.inner
        if self.config.average == "ca":
            so = ndimage.uniform_filter(power, self.outer, mode=mode) * (od * orr)
            si = ndimage.uniform_filter(power, self.inner, mode=mode) * (idd * ir)
            return np.maximum(so - si, 0) / len(self.ring_d)
        # box sums over Doppler first, then over one-sided range windows: the nearer-range sum
        # [r - n + 1, r] by a running mean, the farther one [r, r + n - 1] is it n - 1 bins on
        outer = ndimage.uniform_filter1d(power, od, axis=0, mode="wrap")
        inner = ndimage.uniform_filter1d(power, idd, axis=0, mode="wrap")
        near_o, far_o = _one_sided(outer, orr // 2 + 1)
        near_i, far_i = _one_sided(inner, ir // 2 + 1)
        near = np.maximum(near_o * od - near_i * idd, 0)
        far = np.maximum(far_o * od - far_i * idd, 0)
        pick = np.minimum if self.config.average == "caso" else np.maximum
        return pick(near, far) / self.half_cells

    def process(self, cube: np.ndarray, keep_maps: bool = False) -> DspResult:
        """Points of one frame from a complex (loops, virtual, samples) ADC cube."""
        cfg = self.config
        spec = self.range_doppler(cube)
        power = self.detection_map(spec)
        noise = self.ca_noise(power)
        cand = power > self.thr * noise
        if cfg.cfar == "os":
            # pre-filter 10 dB below the threshold over the median of each range bin (not the CA
            # mean: a strong neighbour inflates that, which is what OS is for); OS then decides
            floor = np.median(power, axis=0)
            cand = power > (self.thr / 10.0) * floor[None, :]
        cand[:, : self.r_lo] = False
        cand[:, self.r_hi :] = False
        d, r = np.nonzero(cand)
        if cfg.peak_grouping and len(d):
            d, r = self._local_max(power, spec if cfg.signature_grouping else None, d, r)
        if cfg.cfar == "os" and len(d):
            d, r, nz = self._os_filter(power, d, r)
        else:
            nz = noise[d, r]
        p = power[d, r]
        if len(d) > cfg.max_points:
            keep = np.argsort(p / nz)[::-1][: cfg.max_points]
            keep.sort()
            d, r, p, nz = d[keep], r[keep], p[keep], nz[keep]
        if len(d):
            points, src = self._points(spec, power, d, r, p, nz)
            d, r = d[src], r[src]
        else:
            points = empty_points()
        return DspResult(
            points,
            np.stack([d, r], axis=1),
            power if keep_maps else None,
            noise if keep_maps else None,
        )

    def _local_max(self, power, spec, d, r):
        """Peak grouping. Keep cells that are >= their 8 neighbours (Doppler cyclic, range clipped).

        With spec (D, V, R) (signature grouping), the channel vector y of a cell tells a target from
        another target's leakage, which has that target's vector: with p(n -> c) = |y_c^H y_n|^2 /
        |y_c|^2 the power of cell n along c's vector (= P_n for leakage, P_n rho^2 for a target
        at another angle, rho < 1), a cell that is not a local maximum is kept when every
        neighbour has p(n -> c) <= P_c / _GROUP_MARGIN: a weaker target at another angle beside a
        stronger one. And a cell is dropped as a sidelobe when a cell of its range row or Doppler
        column within the CFAR window has p(n -> c) > _SIDELOBE_RATIO * P_c: a strong target's
        Hann sidelobes (-31 dB) pass a CFAR that averages the side away from it (CASO)."""
        D, R = power.shape
        nd = (d[:, None] + _NB_D[None, :]) % D  # (K, 8)
        nr = np.clip(r[:, None] + _NB_R[None, :], 0, R - 1)
        p0 = power[d, r]
        keep = (p0[:, None] >= power[nd, nr]).all(axis=1)
        if spec is None:
            return d[keep], r[keep]
        lose = np.flatnonzero(~keep)
        if len(lose):
            keep[lose] = self._along(spec, d[lose], r[lose], nd[lose], nr[lose], _GROUP_MARGIN)
        d, r = d[keep], r[keep]
        if len(d):
            cd = (d[:, None] + self.cross_d[None, :]) % D
            cr = np.clip(r[:, None] + self.cross_r[None, :], 0, R - 1)
            # only a cell with a far stronger one in its window can be a sidelobe (p(n->c) <= P_n)
            ask = np.flatnonzero((power[cd, cr] > _SIDELOBE_RATIO * power[d, r][:, None]).any(1))
            if len(ask):
                ok = np.ones(len(d), dtype=bool)
                ok[ask] = self._along(spec, d[ask], r[ask], cd[ask], cr[ask], 1 / _SIDELOBE_RATIO)
                d, r = d[ok], r[ok]
        return d, r

    @staticmethod
    def _along(spec, d, r, nd, nr, factor: float) -> np.ndarray:
        """True where every neighbour (nd, nr) (K, M) has factor * |y_c^H y_n|^2 <= |y_c|^4."""
        yc = spec[d, :, r]  # (K, V)
        yn = spec[nd, :, nr]  # (K, M, V)
        along = np.abs(np.einsum("kv,kmv->km", np.conj(yc), yn)) ** 2
        own = np.einsum("kv,kv->k", np.conj(yc), yc).real
        return (factor * along <= (own * own)[:, None]).all(axis=1)

    def _os_filter(self, power, d, r):
        """Ordered-statistic CFAR at candidate cells: noise = os_rank quantile of the ring."""
        dd = (d[:, None] + self.ring_d[None, :]) % self.L
        rr = np.clip(r[:, None] + self.ring_r[None, :], 0, power.shape[1] - 1)
        vals = power[dd, rr]
        nz = np.partition(vals, self.os_k, axis=1)[:, self.os_k]
        ok = power[d, r] > self.thr * nz
        return d[ok], r[ok], nz[ok]

    def _points(self, spec, power, d, r, p, nz) -> tuple[np.ndarray, np.ndarray]:
        """Points of the detected cells, and the detection each point comes from (a cell gives
        a second point when multi-object beamforming finds a second azimuth peak)."""
        cfg = self.config
        ds = self.d_signed[d]
        # sub-bin Doppler (parabola through the log power), used for the TDM phase and the output
        dsf = ds + self._parabola(power, d, r, axis=0)
        y = spec[d, :, r]  # (K, V)
        # TDM-MIMO: slot k fires k*Tc after slot 0; remove the Doppler phase it accumulated (with
        # the whole bin only, half a bin off leaves a 0.1 deg azimuth error between TX0 and TX2)
        if cfg.tdm_compensation:
            y = y * np.exp(-2j * np.pi * np.outer(dsf, self.slot) / (self.L * self.T)).astype(
                np.complex64
            )
        if self.cal is not None:
            y = y * self.cal
        a = y[:, self.az_idx] @ self.az_map  # (K, n_az)
        s = np.abs(sfft.fft(a, n=self.n_fft_az, axis=1, workers=1))
        k = np.argmax(s, axis=1)
        ux = self._peak_ux(s, k)
        src = np.arange(len(d))
        gain = np.ones(len(d))
        if cfg.multi_obj_threshold is not None:
            n = self.n_fft_az
            peaks = (s > np.roll(s, 1, axis=1)) & (s >= np.roll(s, -1, axis=1))
            dist = (np.arange(n)[None, :] - k[:, None]) % n
            dist = np.minimum(dist, n - dist)
            outside = dist >= int(math.ceil(n / self.n_az))  # beyond the main lobe's first null
            cand = np.where(peaks & outside, s, 0.0)
            k2 = np.argmax(cand, axis=1)
            ratio = cand[src, k2] / np.maximum(s[src, k], 1e-30)
            two = np.flatnonzero(ratio >= cfg.multi_obj_threshold)
            if len(two):
                ux = np.concatenate([ux, self._peak_ux(s[two], k2[two])])
                y = np.concatenate([y, y[two]])
                src = np.concatenate([src, two])
                gain = np.concatenate([gain, ratio[two] ** 2])
        uz = np.zeros_like(ux)
        if cfg.elevation and len(self.el_idx):
            steer = np.exp(1j * np.pi * np.outer(ux, self.pos[:, 0])).astype(np.complex64)
            w = y * steer
            e = w[:, self.el_idx].sum(axis=1)
            az = w[:, self.az_idx].sum(axis=1)
            uz = np.clip(-np.angle(e * np.conj(az)) / (np.pi * self.el_dz), -1.0, 1.0)
        norm = np.hypot(ux, uz)
        scale = np.where(norm > 1.0, 1.0 / np.maximum(norm, 1e-12), 1.0)
        ux, uz = ux * scale, uz * scale
        uy = np.sqrt(np.maximum(0.0, 1.0 - ux * ux - uz * uz))
        # sub-bin range and Doppler from a parabola through the log power
        rng = (r + self._parabola(power, d, r, axis=1)) * self.range_step - cfg.range_bias_m
        dop = dsf * self.doppler_step
        rng, dop = rng[src], dop[src]
        snr = 10 * np.log10(np.maximum(p[src] * gain, 1e-30) / np.maximum(nz[src], 1e-30))
        out = np.empty((len(src), 5), dtype=np.float32)
        out[:, 0] = rng * ux
        out[:, 1] = rng * uy
        out[:, 2] = rng * uz
        out[:, 3] = dop
        out[:, 4] = snr
        return out, src

    def _peak_ux(self, s: np.ndarray, k: np.ndarray) -> np.ndarray:
        """u_x = sin(az) cos(el) of azimuth-spectrum peaks k (parabola on log magnitude)."""
        n = self.n_fft_az
        idx = np.arange(len(k))
        lm = np.log(s[idx, (k - 1) % n] + 1e-12)
        l0 = np.log(s[idx, k] + 1e-12)
        lp = np.log(s[idx, (k + 1) % n] + 1e-12)
        den = lm - 2 * l0 + lp
        delta = np.where(den < 0, 0.5 * (lm - lp) / np.where(den < 0, den, -1), 0.0)
        f = (k + delta) / n
        f = np.where(f >= 0.5, f - 1.0, f)
        return np.clip(-2.0 * f, -1.0, 1.0)  # phase -pi x u_x along the array

    @staticmethod
    def _parabola(power, d, r, axis: int) -> np.ndarray:
        D, R = power.shape
        if axis == 1:
            lm = power[d, np.clip(r - 1, 0, R - 1)]
            lp = power[d, np.clip(r + 1, 0, R - 1)]
        else:
            lm = power[(d - 1) % D, r]
            lp = power[(d + 1) % D, r]
        lm, l0, lp = np.log(lm + 1e-30), np.log(power[d, r] + 1e-30), np.log(lp + 1e-30)
        den = lm - 2 * l0 + lp
        return np.clip(
            np.where(den < 0, 0.5 * (lm - lp) / np.where(den < 0, den, -1), 0.0), -0.5, 0.5
        )


def _one_sided(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Sums of x over range windows [r - n + 1, r] and [r, r + n - 1] (axis 1, edge values
    repeated beyond the ends), each (D, R) float32."""
    R = x.shape[1]
    near = ndimage.uniform_filter1d(x, n, axis=1, mode="nearest", origin=(n - 1) // 2) * n
    far = np.empty_like(near)
    k = max(R - n + 1, 0)
    far[:, :k] = near[:, n - 1 :]
    # the last n - 1 bins: the rest of the row, then the last bin repeated
    tail = x[:, k:]
    rest = np.cumsum(tail[:, ::-1], axis=1, dtype=np.float64)[:, ::-1]
    far[:, k:] = rest + (np.arange(k, R) + n - R)[None, :] * x[:, R - 1 : R]
    return near, far


def check_adc_format(cfg) -> None:
    """Refuse cfgs whose ADC output this raw path does not decode: adcCfg must say 16 bits
    (numADCBits 2) and complex samples (adcOutputFmt 1 = complex 1x or 2 = complex 2x)."""
    for lineno, cmd, args in cfg.commands:
        if cmd == "adcCfg":
            bits, fmt = int(float(args[0])), int(float(args[1]))
            if bits != 2:
                raise ConfigError(
                    f"{cfg.path}:{lineno}: adcCfg numADCBits {bits}: the DCA1000 raw path reads "
                    "16-bit samples only (numADCBits 2)"
                )
            if fmt not in (1, 2):
                raise ConfigError(
                    f"{cfg.path}:{lineno}: adcCfg adcOutputFmt {fmt}: real-only ADC output is not "
                    "supported (use 1 = complex 1x or 2 = complex 2x)"
                )


def make_dsp(
    cfg,
    layout: str = "4lane",
    antenna: AntennaLayout = AWR2243BOOST,
    iq_swap: bool = False,
    **overrides,
) -> tuple[FrameGeometry, RadarDsp]:
    """FrameGeometry and RadarDsp for a parsed .cfg (drivers.ti.cfg.RadarCfg).

    layout: "4lane" (AR1243/AWR2243) or "2lane" (xWR16xx/18xx/68xx); antenna: the board's
    AntennaLayout; iq_swap: Q before I in the stream; overrides: DspConfig fields that win
    over the cfg (e.g. cfar="os").
    """
    check_adc_format(cfg)
    geom = FrameGeometry.from_chirp(cfg.chirp, layout, iq_swap)
    return geom, RadarDsp(cfg.chirp, geom, DspConfig.from_cfg(cfg, **overrides), antenna)


__all__ = ["DspConfig", "DspResult", "RadarDsp", "check_adc_format", "make_dsp"]
