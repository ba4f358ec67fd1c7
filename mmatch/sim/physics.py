"""Physics as a family: the constants no deployment can know, each drawn per scene from a range.

`nominal` fixes every constant at a central value; `wide` draws each one per scene from the
documented range below (uniform, or log-uniform for scale factors). A TOML file can narrow or
move any range (`mmatch sim --physics FILE.toml`, keys as below, values `[lo, hi]` or a single
number); every range is checked at load and a bad one is refused naming its key.

What each constant means (units in the key name or the description):

| key | nominal | wide range | what it sets |
| --- | --- | --- | --- |
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from mmatch.errors import ConfigError


@dataclass(frozen=True)
class Knob:
    """One uncertain constant: its nominal value, its wide range, and the checks it must pass.

    lo_limit / hi_limit: the physically possible interval (a range outside it is refused);
    log: draw log-uniformly (scale factors); integer: round the draw.
    """

    nominal: float
    wide: tuple[float, float]
    doc: str
    lo_limit: float = 0.0
    hi_limit: float = float("inf")
    log: bool = False
    integer: bool = False


KNOBS: dict[str, Knob] = {
    # radar: angle accuracy (the model and its grounding in our DSP: mmatch/sim/radar_errors.py)
    "angle_noise_scale": Knob(1.0, (0.8, 1.5), "factor on the DSP-grounded angle errors", log=True,
                              lo_limit=0.05, hi_limit=10.0),
    "channels_az": Knob(8, (8, 12), "virtual channels across azimuth", lo_limit=2, hi_limit=256, integer=True),
    "channels_el": Knob(4, (2, 4), "virtual channels of the raised row (elevation)", lo_limit=0, hi_limit=64,
                        integer=True),
    "glint_factor": Knob(1.0, (0.8, 1.3), "spread of an extended target's scatterers, share of its angular extent",
                         hi_limit=5.0),
    "calib_bias_az_deg": Knob(0.25, (0.0, 0.5), "largest per-radar azimuth calibration bias, deg", hi_limit=10.0),
    "calib_bias_el_deg": Knob(0.5, (0.0, 1.0), "largest per-radar elevation calibration bias, deg", hi_limit=10.0),
    "calib_floor_az_deg": Knob(0.3, (0.1, 0.5), "per-point azimuth calibration residual, deg (1 sigma)",
                               hi_limit=10.0),
    "calib_floor_el_deg": Knob(0.6, (0.2, 1.0), "per-point elevation calibration residual, deg (1 sigma)",
                               hi_limit=10.0),
    "range_sigma_m": Knob(0.06, (0.04, 0.15), "range noise, m (1 sigma)", hi_limit=5.0),
    "doppler_sigma_mps": Knob(0.06, (0.04, 0.15), "Doppler noise at high SNR, m/s (1 sigma)", hi_limit=5.0),
    "wheel_share": Knob(0.12, (0.05, 0.25), "share of a moving vehicle's returns from its wheels (micro-Doppler)",
                        hi_limit=1.0),
    "snr_offset_db": Knob(0.0, (-4.0, 4.0), "radar sensitivity offset on every return's SNR, dB",
                          lo_limit=-40.0, hi_limit=40.0),
    "detection_threshold_db": Knob(8.0, (6.0, 11.0), "centre of the soft CFAR detection threshold, dB",
                                   lo_limit=-10.0, hi_limit=40.0),
    "points_scale": Knob(1.0, (0.7, 1.3), "factor on the returns per vehicle", log=True, lo_limit=0.05,
                         hi_limit=10.0),
    "clutter_rate": Knob(6.0, (3.0, 12.0), "isolated false radar points per frame (mean)", hi_limit=1000.0),
    "ghost_prob": Knob(0.12, (0.05, 0.22), "probability a vehicle return has a multipath ghost", hi_limit=1.0),
    "radar_yaw_error_deg": Knob(2.0, (0.5, 4.0), "radar mounting yaw off the vehicle axis, deg (1 sigma)",
                                hi_limit=20.0),
    # camera and detector
    "false_detection_rate": Knob(0.75, (0.5, 1.0), "false camera detections per frame (mean)", hi_limit=50.0),
    "false_on_vehicle_share": Knob(0.3, (0.2, 0.4), "share of false detections on part of a real vehicle",
                                   hi_limit=1.0),
    "false_on_structure_share": Knob(0.2, (0.1, 0.3), "share of false detections on roadside structure",
                                     hi_limit=1.0),
    "miss_prob": Knob(0.06, (0.03, 0.12), "probability an unoccluded vehicle is missed", hi_limit=1.0),
    "box_sigma_px": Knob(2.0, (1.0, 4.0), "box corner noise, px (1 sigma)", hi_limit=100.0),
    "depth_sigma_rel": Knob(0.1, (0.05, 0.18), "monocular depth error, relative (1 sigma)", hi_limit=1.0),
    "descriptor_pixels": Knob(256, (96, 384), "pixels per box behind the appearance descriptor", lo_limit=8,
                              hi_limit=100000, integer=True),
    "camera_hue_shift": Knob(0.0, (-6.0, 6.0), "hue shift of one camera's colour response (OpenCV hue units)",
                             lo_limit=-90.0, hi_limit=90.0),
    "camera_saturation_gain": Knob(1.0, (0.8, 1.25), "saturation gain of one camera", log=True, lo_limit=0.1,
                                   hi_limit=10.0),
    "score_slope": Knob(1.0, (0.6, 1.4), "detector score calibration: slope on the logit", log=True,
                        lo_limit=0.05, hi_limit=20.0),
    "score_bias": Knob(0.0, (-0.8, 0.5), "detector score calibration: bias on the logit", lo_limit=-10.0,
                       hi_limit=10.0),
    "extrinsic_rot_err_deg": Knob(0.3, (0.0, 1.0), "camera-radar extrinsic rotation error, deg (max)",
                                  hi_limit=20.0),
    "extrinsic_trans_err_m": Knob(0.02, (0.0, 0.05), "camera-radar extrinsic translation error, m (max)",
                                  hi_limit=2.0),
    "camera_focal_scale": Knob(1.0, (1.0, 1.0), "factor on the cameras' focal length (900-1100 px at 1280 px: "
                               "30-35 deg either side); each vehicle knows its own (K), so `wide` keeps ours and "
                               "cfg/physics/cameras-*.toml test others", log=True, lo_limit=0.2, hi_limit=5.0),
    # scene composition
    "few_covisible_share": Knob(0.1, (0.1, 0.1), "share of scenes drawn with fewer than two co-visible vehicles",
                                hi_limit=1.0),
}

PRESETS = ("nominal", "wide")


def _table() -> str:
    rows = []
    for key, k in KNOBS.items():
        rows.append(f"| `{key}` | {k.nominal:g} | {k.wide[0]:g} - {k.wide[1]:g} | {k.doc} |")
    return "\n".join(rows)


__doc__ = (__doc__ or "") + _table() + "\n"


@dataclass(frozen=True)
class PhysicsFamily:
    """Ranges (lo, hi) per knob; a scene draws one value of each (`draw`)."""

    name: str
    ranges: dict[str, tuple[float, float]]

    def draw(self, rng: np.random.Generator) -> "PhysicsSample":
        values = {}
        for key, knob in KNOBS.items():
            lo, hi = self.ranges[key]
            if hi == lo:
                v = lo
            elif knob.log and lo > 0:
                v = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
            else:
                v = float(rng.uniform(lo, hi))
            values[key] = float(round(v)) if knob.integer else v
        return PhysicsSample(**values)


@dataclass(frozen=True)
class PhysicsSample:
    """The constants of one scene (every knob of KNOBS, drawn)."""

    angle_noise_scale: float
    channels_az: float
    channels_el: float
    glint_factor: float
    calib_bias_az_deg: float
    calib_bias_el_deg: float
    calib_floor_az_deg: float
    calib_floor_el_deg: float
    range_sigma_m: float
    doppler_sigma_mps: float
    wheel_share: float
    snr_offset_db: float
    detection_threshold_db: float
    points_scale: float
    clutter_rate: float
    ghost_prob: float
    radar_yaw_error_deg: float
    false_detection_rate: float
    false_on_vehicle_share: float
    false_on_structure_share: float
    miss_prob: float
    box_sigma_px: float
    depth_sigma_rel: float
    descriptor_pixels: float
    camera_hue_shift: float
    camera_saturation_gain: float
    score_slope: float
    score_bias: float
    extrinsic_rot_err_deg: float
    extrinsic_trans_err_m: float
    camera_focal_scale: float
    few_covisible_share: float

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


def nominal_sample() -> PhysicsSample:
    return PhysicsSample(**{k: float(v.nominal) for k, v in KNOBS.items()})


def _check_range(key: str, lo: float, hi: float) -> None:
    knob = KNOBS[key]
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ConfigError(f"physics.{key}: range [{lo}, {hi}] is not finite")
    if lo > hi:
        raise ConfigError(f"physics.{key}: empty range [{lo}, {hi}] (low above high)")
    if lo < knob.lo_limit or hi > knob.hi_limit:
        raise ConfigError(f"physics.{key}: range [{lo}, {hi}] outside the possible "
                          f"[{knob.lo_limit:g}, {knob.hi_limit:g}] ({knob.doc})")


def family(spec: str | Path = "wide") -> PhysicsFamily:
    """`nominal`, `wide`, or a TOML file of overrides on top of `wide`.

    The file holds `key = [lo, hi]` or `key = value` at top level (or under `[physics]`);
    unknown keys and impossible ranges raise ConfigError naming the key.
    """
    spec = str(spec)
    if spec == "nominal":
        return PhysicsFamily("nominal", {k: (float(v.nominal), float(v.nominal)) for k, v in KNOBS.items()})
    ranges = {k: (float(v.wide[0]), float(v.wide[1])) for k, v in KNOBS.items()}
    if spec == "wide":
        return PhysicsFamily("wide", ranges)
    path = Path(spec)
    if not path.is_file():
        raise ConfigError(f"physics: {spec!r} is neither nominal, wide nor a TOML file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"physics: {path}: {exc}") from exc
    data = data.get("physics", data)
    for key, value in data.items():
        if key not in KNOBS:
            raise ConfigError(f"physics.{key}: unknown key; known: {', '.join(KNOBS)}")
        if isinstance(value, bool):
            raise ConfigError(f"physics.{key}: expected a number or [lo, hi], got {value!r}")
        if isinstance(value, (int, float)):
            lo = hi = float(value)
        elif isinstance(value, list) and len(value) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
            lo, hi = float(value[0]), float(value[1])
        else:
            raise ConfigError(f"physics.{key}: expected a number or [lo, hi], got {value!r}")
        ranges[key] = (lo, hi)
    for key, (lo, hi) in ranges.items():
        _check_range(key, lo, hi)
    if ranges["false_on_vehicle_share"][1] + ranges["false_on_structure_share"][1] > 1.0:
        raise ConfigError("physics.false_on_vehicle_share + false_on_structure_share: may exceed 1")
    return PhysicsFamily(path.stem, ranges)


for _key, _knob in KNOBS.items():            # the documented ranges pass their own checks
    _check_range(_key, *_knob.wide)
    _check_range(_key, _knob.nominal, _knob.nominal)
