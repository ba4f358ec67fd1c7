"""TI mmWave CLI .cfg files: parse, validate and derive the chirp parameters.

A .cfg is the list of CLI commands a TI demo firmware accepts on its config UART
(ti_formats.md section 1c). `parse_cfg` checks every line *before* anything is sent to a
device: unknown commands, wrong argument counts, non-numeric arguments and physically
impossible profiles are refused with a `ConfigError` naming ``source:line``.

Derived quantities follow ti_formats.md section 1c (c = 3e8 m/s, f0 = profile start
frequency):

* num_tx = popcount of the TX used by the chirps of one frame; num_rx = popcount(rx mask)
* chirps_per_frame = (chirpEndIdx - chirpStartIdx + 1) * numLoops
* num_doppler_bins = chirps_per_frame / num_tx (= numLoops when every chirp uses one TX)
* num_range_bins = next power of two >= numAdcSamples
* range_resolution = c * fs / (2 * S * N)         (fs in Hz, S in Hz/s, N = numAdcSamples)
* range_idx_to_m = c * fs / (2 * S * num_range_bins)
* max_range = 0.9 * fs * c / (2 * S)               (IF-bandwidth limit with 10 % margin)
* Tc = idleTime + rampEndTime (us)
* doppler_resolution = c / (2 * f0 * Tc * num_doppler_bins * num_tx)
* max_velocity = c / (4 * f0 * Tc * num_tx)

Advanced-frame configs (``dfeDataOutputMode 3``) are described by sub-frame 0.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from mmatch.errors import ConfigError

log = logging.getLogger(__name__)

SPEED_OF_LIGHT = 3e8
"""m/s, the value TI tools and the reference formulas use."""

VEHICLE_MIN_VELOCITY_MPS = 20.0
"""Unambiguous radial speed (m/s) below which a profile is flagged as unfit for traffic."""

VEHICLE_MIN_RANGE_M = 100.0
"""Maximum range (m) below which a profile is flagged as short for traffic."""

# command -> allowed argument counts (ti_formats.md 1c; SDK 1.x-3.x and the people-counting
# labs). A set of ints; None in place of the set means "any count" (checked elsewhere).
_ARGC: dict[str, frozenset[int] | None] = {
    "sensorStop": frozenset({0, 1}),
    "flushCfg": frozenset({0}),
    "sensorStart": frozenset({0, 1}),
    "dfeDataOutputMode": frozenset({1}),
    "channelCfg": frozenset({3}),
    "adcCfg": frozenset({2}),
    "adcbufCfg": frozenset({4, 5}),
    "profileCfg": frozenset({14}),
    "chirpCfg": frozenset({8}),
    "frameCfg": frozenset({7}),
    "advFrameCfg": frozenset({5}),
    "subFrameCfg": frozenset({10}),
    "lowPower": frozenset({2}),
    "guiMonitor": frozenset({6, 7}),
    "cfarCfg": frozenset({6, 8, 9}),
    "multiObjBeamForming": frozenset({2, 3}),
    "clutterRemoval": frozenset({1, 2}),
    "calibDcRangeSig": frozenset({4, 5}),
    "extendedMaxVelocity": frozenset({2}),
    "lvdsStreamCfg": frozenset({4}),
    "compRangeBiasAndRxChanPhase": None,  # rangeBias + (re, im) per virtual antenna
    "measureRangeBiasAndRxChanPhase": frozenset({3}),
    "CQRxSatMonitor": frozenset({5}),
    "CQSigImgMonitor": frozenset({3}),
    "analogMonitor": frozenset({2}),
    "aoaFovCfg": frozenset({5}),
    "cfarFovCfg": frozenset({4}),
    "calibData": frozenset({3}),
    "bpmCfg": frozenset({4}),
    "nearFieldCfg": frozenset({4}),
    "baudRate": frozenset({1}),
    # Industrial toolbox people counting / tracking labs
    "dynamicRACfarCfg": frozenset({11, 12}),
    "staticRACfarCfg": frozenset({11, 12}),
    "dynamicRangeAngleCfg": frozenset({4}),
    "dynamic2DAngleCfg": frozenset({7}),
    "staticRangeAngleCfg": frozenset({3}),
    "fineMotionCfg": frozenset({5}),
    "trackingCfg": frozenset({8}),
    "SceneryParam": frozenset({4, 6}),
    "GatingParam": frozenset({4, 5}),
    "StateParam": frozenset({4, 6}),
    "AllocationParam": frozenset({6}),
    "MaxAcceleration": frozenset({3}),
    "boundaryBox": frozenset({4, 6}),
    "staticBoundaryBox": frozenset({4, 6}),
    "presenceBoundaryBox": frozenset({4, 6}),
    "sensorPosition": frozenset({2, 3, 5}),
}

KNOWN_COMMANDS: frozenset[str] = frozenset(_ARGC)

# RF bands the TI parts tune to (GHz): xWR14/16/18xx 76-81, xWR68xx 60-64.
_BANDS_GHZ: tuple[tuple[float, float], ...] = ((76.0, 81.0), (60.0, 64.0))
_BAND_MARGIN_GHZ = 0.5


@dataclass(frozen=True)
class ChirpParams:
    """Chirp/frame parameters of one .cfg and what follows from them.

    Times in microseconds unless named otherwise; frequencies in GHz, slope in MHz/us,
    sample rate in ksps; distances in metres, velocities in m/s.
    tx_order: TX index (0-based) of each chirp of one chirp loop, in frame order (from the
    chirpCfg txEnable masks; a chirp with several TX enabled, e.g. BPM, gives its lowest).
    """

    start_freq_ghz: float
    idle_time_us: float
    adc_start_time_us: float
    ramp_end_time_us: float
    slope_mhz_per_us: float
    num_adc_samples: int
    sample_rate_ksps: float
    rx_mask: int
    tx_mask: int
    num_rx: int
    num_tx: int
    tx_order: tuple[int, ...]
    num_loops: int
    chirps_per_frame: int
    frame_period_ms: float
    num_range_bins: int
    num_doppler_bins: int
    range_resolution_m: float
    range_idx_to_m: float
    max_range_m: float
    doppler_resolution_mps: float
    max_velocity_mps: float

    @property
    def chirp_time_us(self) -> float:
        """Tc = idle + ramp end time, us."""
        return self.idle_time_us + self.ramp_end_time_us

    @property
    def bandwidth_mhz(self) -> float:
        """Sampled bandwidth B = S * N / fs, MHz."""
        return self.slope_mhz_per_us * self.num_adc_samples / (self.sample_rate_ksps * 1e-3)


@dataclass(frozen=True)
class RadarCfg:
    """A parsed, validated .cfg.

    commands: (line number, command, args) of every non-comment line, in file order.
    warnings: human-readable concerns that do not stop the cfg (e.g. max velocity too
    low for traffic); also logged at WARNING by `parse_cfg`.
    """

    path: str
    commands: tuple[tuple[int, str, tuple[str, ...]], ...]
    chirp: ChirpParams
    warnings: tuple[str, ...] = ()

    def lines(self) -> list[str]:
        """The commands as CLI lines, comments and blank lines removed, in order."""
        return [" ".join((cmd, *args)) for _, cmd, args in self.commands]


def _next_pow2(n: int) -> int:
    return 1 << max(0, (int(n) - 1).bit_length())


def _popcount(mask: int) -> int:
    return bin(mask).count("1")


class _Line:
    """Numeric access to one command's arguments with errors that name the line."""

    def __init__(self, source: str, lineno: int, cmd: str, args: tuple[str, ...]) -> None:
        self.where = f"{source}:{lineno}"
        self.cmd = cmd
        self.args = args

    def fail(self, msg: str) -> ConfigError:
        return ConfigError(f"{self.where}: {self.cmd}: {msg}")

    def num(self, i: int, name: str) -> float:
        try:
            v = float(self.args[i])
        except ValueError:
            raise self.fail(f"argument {i + 1} ({name}) is not a number: {self.args[i]!r}") from None
        if not math.isfinite(v):
            raise self.fail(f"argument {i + 1} ({name}) is not finite: {self.args[i]!r}")
        return v

    def int(self, i: int, name: str) -> int:
        v = self.num(i, name)
        if v != int(v):
            raise self.fail(f"argument {i + 1} ({name}) must be an integer: {self.args[i]!r}")
        return int(v)


def _tokenize(text: str, source: str) -> tuple[tuple[int, str, tuple[str, ...]], ...]:
    out: list[tuple[int, str, tuple[str, ...]]] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("%"):
            continue
        cmd, *args = line.split()
        allowed = _ARGC.get(cmd, frozenset())
        if cmd not in _ARGC:
            raise ConfigError(f"{source}:{lineno}: unknown command {cmd!r}")
        if cmd == "compRangeBiasAndRxChanPhase":
            if len(args) < 3 or len(args) % 2 == 0:
                raise ConfigError(
                    f"{source}:{lineno}: {cmd}: expected rangeBias plus (re, im) pairs, "
                    f"got {len(args)} arguments")
        elif allowed is not None and len(args) not in allowed:
            want = " or ".join(str(n) for n in sorted(allowed))
            raise ConfigError(
                f"{source}:{lineno}: {cmd}: expected {want} arguments, got {len(args)}")
        out.append((lineno, cmd, tuple(args)))
    return tuple(out)


def check_command(line: str, source: str = "<cli>", lineno: int = 1) -> tuple[str, tuple[str, ...]]:
    """(command, args) of one CLI line; `ConfigError` for an unknown command or a wrong
    argument count (what the firmware itself refuses line by line)."""
    parsed = _tokenize(line, source)
    if not parsed:
        raise ConfigError(f"{source}:{lineno}: empty or comment line")
    _, cmd, args = parsed[0]
    return cmd, args


def _in_band(freq_ghz: float) -> tuple[float, float] | None:
    for lo, hi in _BANDS_GHZ:
        if lo - _BAND_MARGIN_GHZ <= freq_ghz <= hi + _BAND_MARGIN_GHZ:
            return lo, hi
    return None


def parse_cfg(text: str, source: str = "<string>") -> RadarCfg:
    """Parse and validate a TI CLI .cfg text; derive the chirp parameters.

    Raises `ConfigError` naming ``source:line`` on an unknown command, a wrong argument
    count, a non-numeric argument, a physically impossible profile (out-of-band
    frequency, ADC sampling longer than the ramp, chirps longer than the frame period,
    ...) or a missing channelCfg/profileCfg/chirpCfg/frameCfg.
    """
    commands = _tokenize(text, source)
    lines = [_Line(source, n, c, a) for n, c, a in commands]

    def last(cmd: str) -> _Line | None:
        found = [ln for ln in lines if ln.cmd == cmd]
        return found[-1] if found else None

    def need(cmd: str) -> _Line:
        ln = last(cmd)
        if ln is None:
            raise ConfigError(f"{source}: missing {cmd} (needed to derive the chirp parameters)")
        return ln

    chan = need("channelCfg")
    rx_mask = chan.int(0, "rxChannelEn")
    tx_mask = chan.int(1, "txChannelEn")
    if not 0 < rx_mask <= 0xF:
        raise chan.fail(f"rxChannelEn {rx_mask} must enable 1-4 RX (mask 1..15)")
    if not 0 < tx_mask <= 0x7:
        raise chan.fail(f"txChannelEn {tx_mask} must enable 1-3 TX (mask 1..7)")

    profiles: dict[int, _Line] = {}
    for ln in lines:
        if ln.cmd == "profileCfg":
            profiles[ln.int(0, "profileId")] = ln
    if not profiles:
        need("profileCfg")

    chirps: dict[int, tuple[_Line, int, int]] = {}  # chirp idx -> (line, profile id, tx mask)
    for ln in lines:
        if ln.cmd != "chirpCfg":
            continue
        start, end = ln.int(0, "startIdx"), ln.int(1, "endIdx")
        prof, txen = ln.int(2, "profileId"), ln.int(7, "txEnable")
        if start < 0 or end < start:
            raise ln.fail(f"chirp index range {start}..{end} is empty or negative")
        if prof not in profiles:
            raise ln.fail(f"profileId {prof} has no profileCfg")
        if txen <= 0 or txen & ~tx_mask:
            raise ln.fail(f"txEnable {txen} is not a non-empty subset of channelCfg TX mask {tx_mask}")
        for idx in range(start, end + 1):
            chirps[idx] = (ln, prof, txen)
    if not chirps:
        need("chirpCfg")

    mode_ln = last("dfeDataOutputMode")
    mode = mode_ln.int(0, "modeType") if mode_ln else 1
    if mode_ln and mode not in (1, 2, 3):
        raise mode_ln.fail(f"modeType {mode} must be 1 (frame), 2 (continuous) or 3 (advanced)")
    if mode == 3:
        frame_ln = None
        for ln in lines:
            if ln.cmd == "subFrameCfg" and ln.int(0, "subFrameNum") == 0:
                frame_ln = ln
        if frame_ln is None:
            raise ConfigError(f"{source}: advanced frame mode needs subFrameCfg 0")
        c0 = frame_ln.int(2, "chirpStartIdx")
        c1 = c0 + frame_ln.int(3, "numOfChirps") - 1
        loops = frame_ln.int(4, "numLoops")
        period_ms = frame_ln.num(9, "subFramePeriodicity")
    else:
        frame_ln = need("frameCfg")
        c0, c1 = frame_ln.int(0, "chirpStartIdx"), frame_ln.int(1, "chirpEndIdx")
        loops = frame_ln.int(2, "numLoops")
        period_ms = frame_ln.num(4, "framePeriodicity")
    if c1 < c0:
        raise frame_ln.fail(f"chirp range {c0}..{c1} is empty")
    missing = [i for i in range(c0, c1 + 1) if i not in chirps]
    if missing:
        raise frame_ln.fail(f"chirp index {missing[0]} has no chirpCfg")
    if loops < 1:
        raise frame_ln.fail(f"numLoops {loops} must be >= 1")
    if period_ms <= 0:
        raise frame_ln.fail(f"frame period {period_ms} ms must be > 0")

    frame_chirps = [chirps[i] for i in range(c0, c1 + 1)]
    prof_ids = {p for _, p, _ in frame_chirps}
    if len(prof_ids) != 1:
        raise frame_ln.fail(f"chirps {c0}..{c1} mix profiles {sorted(prof_ids)}; one profile per frame is supported")
    prof = profiles[prof_ids.pop()]
    f0 = prof.num(1, "startFreq")
    idle = prof.num(2, "idleTime")
    adc_start = prof.num(3, "adcStartTime")
    ramp_end = prof.num(4, "rampEndTime")
    slope = prof.num(7, "freqSlopeConst")
    n_adc = prof.int(9, "numAdcSamples")
    fs_ksps = prof.num(10, "digOutSampleRate")

    band = _in_band(f0)
    if band is None:
        raise prof.fail(f"startFreq {f0} GHz is outside the 60-64 and 76-81 GHz bands")
    if idle < 0 or adc_start < 0 or ramp_end <= 0:
        raise prof.fail(f"times must be non-negative and rampEndTime > 0 (idle {idle}, "
                        f"adcStart {adc_start}, rampEnd {ramp_end} us)")
    if slope <= 0:
        raise prof.fail(f"freqSlopeConst {slope} MHz/us must be > 0")
    if n_adc < 1:
        raise prof.fail(f"numAdcSamples {n_adc} must be >= 1")
    if not 0 < fs_ksps <= 50000:
        raise prof.fail(f"digOutSampleRate {fs_ksps} ksps must be in (0, 50000]")
    sampling_us = n_adc / (fs_ksps * 1e-3)
    if adc_start + sampling_us > ramp_end:
        raise prof.fail(
            f"ADC sampling ends at {adc_start + sampling_us:.2f} us (adcStart {adc_start} + "
            f"{n_adc} samples at {fs_ksps} ksps), after the ramp ends at {ramp_end} us")
    f_end = f0 + slope * ramp_end * 1e-3
    if f_end > band[1] + _BAND_MARGIN_GHZ:
        raise prof.fail(f"ramp ends at {f_end:.2f} GHz, above the {band[0]:.0f}-{band[1]:.0f} GHz band")

    tx_order = tuple((txen & -txen).bit_length() - 1 for _, _, txen in frame_chirps)
    used_tx = 0
    for _, _, txen in frame_chirps:
        used_tx |= txen
    num_tx = _popcount(used_tx)
    num_rx = _popcount(rx_mask)
    chirps_per_loop = c1 - c0 + 1
    chirps_per_frame = chirps_per_loop * loops
    tc_us = idle + ramp_end
    active_ms = chirps_per_frame * tc_us * 1e-3
    if mode != 2 and active_ms > period_ms:
        raise frame_ln.fail(
            f"{chirps_per_frame} chirps of {tc_us:.2f} us take {active_ms:.3f} ms, longer than "
            f"the frame period {period_ms} ms")

    fs = fs_ksps * 1e3
    s_hz = slope * 1e12
    f0_hz = f0 * 1e9
    c = SPEED_OF_LIGHT
    n_range = _next_pow2(n_adc)
    n_doppler = max(1, chirps_per_frame // num_tx)
    chirp = ChirpParams(
        start_freq_ghz=f0, idle_time_us=idle, adc_start_time_us=adc_start,
        ramp_end_time_us=ramp_end, slope_mhz_per_us=slope, num_adc_samples=n_adc,
        sample_rate_ksps=fs_ksps, rx_mask=rx_mask, tx_mask=tx_mask, num_rx=num_rx,
        num_tx=num_tx, tx_order=tx_order, num_loops=loops, chirps_per_frame=chirps_per_frame,
        frame_period_ms=period_ms, num_range_bins=n_range, num_doppler_bins=n_doppler,
        range_resolution_m=c * fs / (2 * s_hz * n_adc),
        range_idx_to_m=c * fs / (2 * s_hz * n_range),
        max_range_m=0.9 * fs * c / (2 * s_hz),
        doppler_resolution_mps=c / (2 * f0_hz * tc_us * 1e-6 * n_doppler * num_tx),
        max_velocity_mps=c / (4 * f0_hz * tc_us * 1e-6 * num_tx),
    )
    warnings = tuple(vehicle_warnings(chirp))
    for w in warnings:
        log.warning("%s: %s", source, w)
    return RadarCfg(path=source, commands=commands, chirp=chirp, warnings=warnings)


def vehicle_warnings(chirp: ChirpParams, min_velocity_mps: float = VEHICLE_MIN_VELOCITY_MPS,
                     min_range_m: float = VEHICLE_MIN_RANGE_M) -> list[str]:
    """Reasons a profile is unfit for road traffic (empty when it is fit).

    Radial speeds beyond +-max_velocity alias (a car closing at 25 m/s reads as going
    away), so vehicles need max_velocity well above typical relative speeds.
    """
    out = []
    if chirp.max_velocity_mps < min_velocity_mps:
        out.append(f"max velocity {chirp.max_velocity_mps:.2f} m/s is below the "
                   f"{min_velocity_mps:.0f} m/s vehicles need (shorten the chirp or use fewer TX)")
    if chirp.max_range_m < min_range_m:
        out.append(f"max range {chirp.max_range_m:.1f} m is below {min_range_m:.0f} m")
    return out


def load_cfg(path: str | Path) -> RadarCfg:
    """Read and parse a .cfg file (see `parse_cfg`); errors name ``path:line``."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from exc
    return parse_cfg(text, source=str(p))
