"""Angle errors of our DSP on synthesised raw ADC, next to the simulator's angle error model.

Grounds mmatch/sim/radar_errors.py in our own raw path: frames of the AWR2243 3 TX x 4 RX cfg
(the bench cfg) are synthesised with targets on a lattice of range-Doppler cells (`SPACING`
bins apart in range and Doppler, so no target sits in another's CFAR window or sidelobes), each
at a random sub-bin position, azimuth (-60..60 deg), elevation (-5..5 deg) and SNR (-42..+25 dB
per ADC sample, which the DSP reports as about 0..67 dB). Point targets are one scatterer;
vehicles are the part of a vehicle face in one range-Doppler cell (synth.extended_target: 2-5
scatterers with exponential powers over a face 0.5-2 m wide and 0.3-1 m high, 0.2 m deep).
RadarDsp processes each frame with its CFAR threshold lowered to `THRESHOLD_DB` (the cfg's
15 dB would leave the weak bands empty); every target is matched to the nearest point within
1.5 cells. The error of a match is the point's azimuth / elevation minus the target's (a
vehicle's: the centre of its face).

The model's errors are drawn for the very same points (their reported SNR, true direction and
angular extent), `draws` times each, and both are summarised per band of the reported SNR.
`mmatch dsp --angle-study` prints the tables.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mmatch.sim.radar_errors import AngleErrorSpec, draw_angle_errors

from .dsp import make_dsp
from .synth import Target, extended_target, synth_cube

BANDS: tuple[tuple[float, float], ...] = ((5, 10), (10, 15), (15, 20), (20, 30), (30, 45))
"""Bands of the SNR our DSP reports (dB) in which the model is held to the DSP."""

TOP_BAND: tuple[float, float] = (45, math.inf)
"""Shown, not held: above 45 dB the DSP's reported SNR saturates (its own Hann leakage reaches
the CFAR ring) and the study's strongest vehicles (+25 dB per ADC sample at most) are seldom
faded, so the model, which takes the reported SNR at face value, overstates the errors there."""

THRESHOLD_DB = 5.0
"""CFAR threshold of the study (dB over the CA noise estimate)."""

SPACING = 16
"""Range and Doppler bins between lattice targets: outside each other's CFAR window, and the
Hann sidelobes of a 67 dB target are below the noise there (-79 dB)."""

AZ_GROUPS: tuple[tuple[float, float], ...] = ((0, 20), (20, 40), (40, 60))
"""Groups of |azimuth| (deg) of the per-azimuth table."""


@dataclass(frozen=True)
class StudySample:
    """Matched detections of a study run (arrays of one length, angles in deg).

    snr_db: SNR the DSP reports; az_deg / el_deg: true direction; extent_az_deg / extent_el_deg:
    the target's angular width / height (0 for point targets); d_az_deg / d_el_deg: DSP error
    (measured minus true); range_m: true range. placed: targets synthesised, matched <= placed.
    """

    snr_db: np.ndarray
    az_deg: np.ndarray
    el_deg: np.ndarray
    extent_az_deg: np.ndarray
    extent_el_deg: np.ndarray
    d_az_deg: np.ndarray
    d_el_deg: np.ndarray
    range_m: np.ndarray
    placed: int


@dataclass(frozen=True)
class BandRow:
    """One band of the table: DSP and model median / p90 of |error| (deg), azimuth and elevation."""

    lo: float
    hi: float
    n: int
    dsp_az: tuple[float, float]
    model_az: tuple[float, float]
    dsp_el: tuple[float, float]
    model_el: tuple[float, float]


def _study_cfg():
    from mmatch.drivers.ti.cfg import parse_cfg

    from .bench import AWR2243_BENCH_CFG

    return parse_cfg(AWR2243_BENCH_CFG, "<angle-study>")


def run_study(extended: bool, frames: int, seed: int = 0, cfg=None) -> StudySample:
    """Synthesise `frames` frames of point targets (extended=False) or vehicles, run the DSP and
    return the matched detections. cfg: a drivers.ti.cfg.RadarCfg (default: the bench cfg)."""
    cfg = cfg if cfg is not None else _study_cfg()
    chirp = cfg.chirp
    geom, dsp = make_dsp(cfg, threshold_db=THRESHOLD_DB)
    rs, dstep = dsp.range_step, dsp.doppler_step
    half = dsp.L // 2
    rbins = np.arange(max(dsp.r_lo, 20), dsp.r_hi - 8, SPACING)
    ncol = max(1, (2 * half - SPACING) // SPACING)
    dbins = np.round((np.arange(ncol) - (ncol - 1) / 2) * SPACING).astype(int)
    rng = np.random.default_rng(seed)
    cols: dict[str, list] = {k: [] for k in ("snr", "az", "el", "ea", "ee", "daz", "del", "r")}
    placed = 0
    for _ in range(frames):
        vel = (dbins + rng.uniform(-0.5, 0.5, len(dbins))) * dstep  # one velocity per column
        targets: list[Target] = []
        truth = []
        for rb in rbins:
            for v in vel:
                r = (rb + rng.uniform(-0.5, 0.5)) * rs
                az, el = rng.uniform(-60, 60), rng.uniform(-5, 5)
                snr = rng.uniform(-42, 25)
                if extended:
                    w, h = rng.uniform(0.5, 2.0), rng.uniform(0.3, 1.0)
                    k = int(rng.integers(2, 6))
                    targets += extended_target(rng, r, v, az, el, w, h, snr, k)
                    ea, ee = math.degrees(w / r), math.degrees(h / r)
                else:
                    targets.append(Target(r, v, az, el, snr))
                    ea = ee = 0.0
                truth.append((r, v, az, el, ea, ee))
        placed += len(truth)
        pts = dsp.process(synth_cube(chirp, geom, targets, rng=rng)).points
        if not len(pts):
            continue
        t = np.asarray(truth)
        pr = np.linalg.norm(pts[:, :3], axis=1)
        cell = np.hypot(
            (pr[None, :] - t[:, 0:1]) / rs, (pts[None, :, 3] - t[:, 1:2]) / dstep
        )  # (targets, points)
        best = np.argmin(cell, axis=1)
        ok = cell[np.arange(len(t)), best] < 1.5
        i, t = best[ok], t[ok]
        p = pts[i]
        cols["snr"].append(p[:, 4])
        cols["az"].append(t[:, 2])
        cols["el"].append(t[:, 3])
        cols["ea"].append(t[:, 4])
        cols["ee"].append(t[:, 5])
        cols["daz"].append(np.degrees(np.arctan2(p[:, 0], p[:, 1])) - t[:, 2])
        cols["del"].append(np.degrees(np.arcsin(np.clip(p[:, 2] / pr[i], -1, 1))) - t[:, 3])
        cols["r"].append(t[:, 0])
    c = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    return StudySample(
        c["snr"], c["az"], c["el"], c["ea"], c["ee"], c["daz"], c["del"], c["r"], placed
    )


def model_errors(
    sample: StudySample, spec: AngleErrorSpec = AngleErrorSpec(), draws: int = 40, seed: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """The model's (d_az, d_el) in deg for every matched point, (draws, n) each."""
    rng = np.random.default_rng(seed)
    n = len(sample.snr_db)
    tile = lambda a: np.tile(np.radians(a), draws)  # noqa: E731
    d_az, d_el = draw_angle_errors(
        rng,
        np.tile(sample.snr_db, draws),
        tile(sample.az_deg),
        tile(sample.el_deg),
        tile(sample.extent_az_deg),
        tile(sample.extent_el_deg),
        spec,
    )
    return np.degrees(d_az).reshape(draws, n), np.degrees(d_el).reshape(draws, n)


def _stats(e: np.ndarray) -> tuple[float, float]:
    a = np.abs(e.ravel())
    if not len(a):
        return math.nan, math.nan
    return float(np.median(a)), float(np.percentile(a, 90))


def _rows(
    sample: StudySample,
    model: tuple[np.ndarray, np.ndarray],
    groups: list[tuple[float, float, np.ndarray]],
) -> list[BandRow]:
    m_az, m_el = model
    return [
        BandRow(
            lo,
            hi,
            int(sel.sum()),
            _stats(sample.d_az_deg[sel]),
            _stats(m_az[:, sel]),
            _stats(sample.d_el_deg[sel]),
            _stats(m_el[:, sel]),
        )
        for lo, hi, sel in groups
    ]


def band_table(
    sample: StudySample,
    spec: AngleErrorSpec = AngleErrorSpec(),
    bands: tuple[tuple[float, float], ...] = BANDS,
    draws: int = 20,
) -> list[BandRow]:
    """Per band of reported SNR: DSP vs model median / p90 of |error|, azimuth and elevation."""
    snr = sample.snr_db
    groups = [(lo, hi, (snr >= lo) & (snr < hi)) for lo, hi in bands]
    return _rows(sample, model_errors(sample, spec, draws), groups)


def azimuth_table(
    sample: StudySample,
    spec: AngleErrorSpec = AngleErrorSpec(),
    snr_band: tuple[float, float] = (15, 30),
    draws: int = 20,
) -> list[BandRow]:
    """Like band_table, over groups of |azimuth| (AZ_GROUPS, deg) within one SNR band."""
    snr, az = sample.snr_db, np.abs(sample.az_deg)
    in_band = (snr >= snr_band[0]) & (snr < snr_band[1])
    groups = [(lo, hi, in_band & (az >= lo) & (az < hi)) for lo, hi in AZ_GROUPS]
    return _rows(sample, model_errors(sample, spec, draws), groups)


def format_rows(title: str, key: str, rows: list[BandRow]) -> str:
    """A text table: one line per row, DSP / model median and p90 (deg) and their ratio."""

    def cell(d: tuple[float, float], m: tuple[float, float]) -> str:
        return "  ".join(f"{d[i]:6.2f} {m[i]:6.2f} {m[i] / d[i] - 1:+4.0%}" for i in (0, 1))

    head = f"{'':14}{'azimuth: median':>22}{'p90':>21}  {'elevation: median':>22}{'p90':>21}"
    sub = f"{key:>9} {'n':>4}" + ("    DSP  model  diff" * 4)
    lines = [title, head, sub]
    for r in rows:
        band = f">{r.lo:g}" if math.isinf(r.hi) else f"{r.lo:g}-{r.hi:g}"
        lines.append(
            f"{band:>9} {r.n:4d}  {cell(r.dsp_az, r.model_az)}  {cell(r.dsp_el, r.model_el)}"
        )
    return "\n".join(lines)


__all__ = [
    "AZ_GROUPS",
    "BANDS",
    "BandRow",
    "StudySample",
    "SPACING",
    "THRESHOLD_DB",
    "TOP_BAND",
    "azimuth_table",
    "band_table",
    "format_rows",
    "model_errors",
    "run_study",
]
