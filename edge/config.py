"""The vehicle service configuration: one typed, nested object loaded from TOML.

Defaults live in code; a file in cfg/ overrides them. Loading refuses unknown keys,
wrong types and impossible values with a `ConfigError` that names the key
(e.g. ``radar.baudrate``). The effective configuration (defaults + file) can be
written back as TOML (`to_toml`) so it is saved beside every log.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mmatch.errors import ConfigError

log = logging.getLogger(__name__)

ROLES = ("cav", "ego", "both")
RADAR_SOURCES = ("uart", "dca1000", "replay", "sim", "scene")  # the loop is driven by radar frames
CAMERA_SOURCES = ("opencv", "oak", "replay", "sim", "scene", "none")


def _opt(default: Any, *, choices: tuple | None = None, lo: float | None = None,
         hi: float | None = None, lo_open: bool = False, doc: str = "") -> Any:
    """A dataclass field with its validation rules kept as metadata."""
    meta = {"choices": choices, "lo": lo, "hi": hi, "lo_open": lo_open, "doc": doc}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class VehicleSection:
    """Who this process is."""

    id: str = _opt("vehicle", doc="vehicle id; a path segment of the Zenoh key expressions")
    role: str = _opt("cav", choices=ROLES, doc="cav publishes shared frames, ego fuses, both does both")


@dataclass(frozen=True)
class RadarSection:
    """The radar source (named backend) and its settings."""

    source: str = _opt("sim", choices=RADAR_SOURCES, doc="radar backend; its frames drive the loop")
    port: str = _opt("", doc="uart: data port (device path or pyserial URL)")
    baudrate: int = _opt(921600, lo=1200, hi=12_000_000, doc="uart: data port baud rate")
    cli_port: str = _opt("", doc="uart: CLI port for sending `cfg` at start; empty = do not configure")
    cfg: str = _opt("", doc="radar chirp profile (.cfg); required for dca1000")
    dca_host: str = _opt("192.168.33.30", doc="dca1000: this computer's address on the DCA1000 link")
    dca_fpga_host: str = _opt("192.168.33.180", doc="dca1000: the FPGA's address")
    dca_data_port: int = _opt(4098, lo=1, hi=65535, doc="dca1000: local UDP port of the raw ADC data")
    dca_config_port: int = _opt(4096, lo=1, hi=65535, doc="dca1000: the FPGA's command port")
    dca_local_config_port: int = _opt(4096, lo=0, hi=65535, doc="dca1000: local command port (0 = any)")
    dca_layout: str = _opt("4lane", choices=("4lane", "2lane"),
                            doc="dca1000: LVDS lanes (4lane: AR1243/AWR2243, 2lane: xWR16xx/18xx/68xx)")
    path: str = _opt("", doc="replay: MCAP log or raw UART capture")
    pace: str = _opt("recorded", choices=("recorded", "fast"),
                     doc="replay: at the recorded pace (log times; baud rate for raw captures) or as fast as possible")
    speed: float = _opt(1.0, lo=0.0, lo_open=True, hi=1000.0, doc="replay: pace multiplier")
    height_m: float = _opt(1.0, lo=0.0, hi=10.0, doc="radar mounting height above the road, m")
    reconnect_s: float = _opt(1.0, lo=0.0, lo_open=True, hi=60.0, doc="wait between reopen attempts")
    read_timeout_s: float = _opt(0.2, lo=0.0, lo_open=True, hi=10.0,
                                  doc="longest wait for one read from the radar, s")


@dataclass(frozen=True)
class CameraSection:
    """The camera source (named backend) and its settings."""

    source: str = _opt("sim", choices=CAMERA_SOURCES, doc="camera backend (none: radar only)")
    device: str = _opt("0", doc="opencv: device index, V4L2 path, GStreamer pipeline or video file")
    calibration: str = _opt("", doc="calibration file (K, distortion, image size, T_cam_radar)")
    model: str = _opt("", doc="detector model (ONNX, or NN archive for oak)")
    path: str = _opt("", doc="replay: MCAP log")
    threads: int = _opt(1, lo=1, hi=64, doc="detector inference threads")
    reconnect_s: float = _opt(2.0, lo=0.0, lo_open=True, hi=60.0, doc="wait between reopen attempts, s")


@dataclass(frozen=True)
class SimSection:
    """The simulated sensors: a scenario played over wall-clock time.

    Both processes derive scenario time from the shared clock (time.time()), so they see
    the same world; each samples it at its own frame phase.
    """

    seed: int = _opt(1, lo=0, doc="scenario seed; both vehicles need the same one")
    mode: str = _opt("mixed", choices=("easy", "hard", "mixed"), doc="scenario difficulty")
    rate_hz: float = _opt(20.0, lo=0.0, lo_open=True, hi=1000.0, doc="radar frames per second")
    phase_s: float = _opt(0.0, lo=0.0, hi=10.0, doc="frame phase offset on the shared clock, s")
    view: str = _opt("auto", choices=("auto", "ego", "cav"),
                     doc="which simulated vehicle this process is; auto: cav for role cav, else ego")
    time_offset_s: float = _opt(0.0, doc="scenario time = shared clock + this, s")
    clock_offset_s: float = _opt(0.0, lo=-10.0, hi=10.0,
                                 doc="this vehicle's clock error: stamps = true capture time + this, s")
    covisible: int = _opt(2, lo=0, hi=20,
                          doc="redraw each 10 s world until both cameras see this many common vehicles")
    render_process: bool = _opt(True, doc="render frames in a child process (as a sensor of its own) "
                                          "rather than in a thread of the vehicle process")


@dataclass(frozen=True)
class SceneSection:
    """Scene files as the sensors (radar.source and camera.source "scene"): one drive of
    `mmatch-scene/1` files (docs/formats.md "Sequences", e.g. from `mmatch sim --sequences`),
    each vehicle playing its own side of the files at their capture stamps. Frames are due on
    the drive's clock: a capture stamp t is due at wall time start + (t - the first Ego stamp)."""

    path: str = _opt("", doc="folder of mmatch-scene/1 files of one or more drives")
    sequence: str = _opt("", doc="meta.sequence of the drive to play; empty: the first in the folder")
    view: str = _opt("auto", choices=("auto", "ego", "cav"),
                     doc="which side of the files this vehicle is; auto: cav for role cav, else ego")
    start: float = _opt(0.0, lo=0.0, doc="unix time (s) at which the drive's first Ego frame is due; "
                                         "0: 2 s after start-up. Two vehicles of one drive need the same")
    lead_s: float = _opt(0.0, lo=0.0, hi=5.0,
                         doc="deliver each frame this long before it is due (a CAV of a recording leads "
                             "its Ego, so its shared frames are there first), s")


@dataclass(frozen=True)
class ZenohSection:
    """Zenoh session. Peer mode with explicit endpoints, or client mode to a router."""

    mode: str = _opt("peer", choices=("peer", "client"),
                     doc="peer: vehicles connect directly; client: through a router (`mmatch router`, zenohd)")
    listen: list[str] = _opt([], doc="endpoints to listen on, e.g. tcp/192.168.50.11:7447 (one interface, never all)")
    connect: list[str] = _opt([], doc="endpoints to connect to: the other vehicle (peer) or the router (client)")
    multicast_scouting: bool = _opt(False, doc="find peers by UDP multicast (off: explicit endpoints only)")
    gossip: bool = _opt(False, doc="learn peers from other peers")
    shared_memory: bool = _opt(False, doc="Zenoh shared-memory transport between processes of one computer")
    config_file: str = _opt("", doc="a zenoh JSON5 file; the keys above are applied on top")
    tls_root_ca: str = _opt("", doc="mutual TLS: the fleet CA certificate (PEM, `mmatch keys --tls`); "
                                    "with it every endpoint must be tls/HOST:PORT")
    tls_certificate: str = _opt("", doc="mutual TLS: this vehicle's certificate (PEM; its common name is the "
                                        "vehicle id the access control matches)")
    tls_private_key: str = _opt("", doc="mutual TLS: this vehicle's TLS private key (PEM)")
    tls_verify_name: bool = _opt(True, doc="check the peer's certificate names the host connected to "
                                           "(off for vehicle-to-vehicle links by IP: the CA still vouches)")


@dataclass(frozen=True)
class EgoSection:
    """How the Ego pairs and fuses."""

    cavs: list[str] = _opt([], doc="CAV ids to listen to; empty = every vehicle")
    pair_tolerance_s: float = _opt(0.06, lo=0.0, lo_open=True, hi=5.0,
                                   doc="max |own stamp - CAV stamp| for a pair, s")
    link_timeout_s: float = _opt(0.5, lo=0.0, lo_open=True, hi=60.0,
                                 doc="a CAV with no frame for this long is flagged lost")
    history: int = _opt(16, lo=1, hi=1024, doc="CAV frames kept per sender (keep-newest ring)")
    wait_s: float = _opt(0.035, lo=0.0, hi=1.0,
                         doc="live only: wait for a CAV frame closer in time until own capture + this, s")
    track_max_age_s: float = _opt(0.5, lo=0.0, hi=60.0,
                                  doc="carry each CAV's transform across frames this long (0: off), s")
    confidence_threshold: float = _opt(-1.0, lo=-1.0, hi=1.0,
                                       doc="an estimate less sure than this (its published confidence: P within "
                                           "2 m / 5 deg) is published as 'no estimate'; -1: the defaults, chosen "
                                           "on the wide physics family with a harsher one in view (0.63 a single "
                                           "frame, 0.55 without a heading prior; 0.6 a tracked "
                                           "transform, the pose filter's belief times its "
                                           "spread's mass within 2 m / 5 deg)")
    max_links: int = _opt(8, lo=1, hi=256,
                          doc="every-CAV mode (cavs = []): at most this many CAVs at once; more are refused")
    link_expire_s: float = _opt(30.0, lo=0.0, lo_open=True, hi=3600.0,
                                doc="every-CAV mode: a CAV silent this long is forgotten (frees its link), s")
    frame_budget_s: float = _opt(0.04, lo=0.0, lo_open=True, hi=10.0,
                                 doc="live only: no further CAV is fused once fusing a frame took this long (the CAV "
                                     "fused least recently goes first, so each takes its turn), s")
    max_vehicles: int = _opt(64, lo=1, hi=65535, doc="a received frame with more vehicles is refused")
    max_points: int = _opt(2048, lo=0, hi=65535, doc="... with more vehicle points is refused")
    max_background: int = _opt(2048, lo=0, hi=65535, doc="... with more background points is refused")
    max_range_m: float = _opt(150.0, lo=1.0, hi=327.67,
                              doc="... with a position, centre or depth beyond this (the radar's range), m")


@dataclass(frozen=True)
class LoopSection:
    """The per-vehicle loop: sensor queues and radar-camera pairing."""

    queue_size: int = _opt(2, lo=1, hi=1024, doc="per-sensor queue; the oldest frame is dropped")
    camera_tolerance_s: float = _opt(0.1, lo=0.0, lo_open=True, hi=5.0,
                                     doc="max |radar stamp - camera stamp| to use detections, s")
    camera_wait_s: float = _opt(0.01, lo=0.0, hi=1.0,
                                doc="wait this long at most for detections at least as new as the radar frame")
    status_interval_s: float = _opt(5.0, lo=0.0, lo_open=True, hi=3600.0,
                                     doc="status line, health message and systemd STATUS= every this, s")
    gil_switch_ms: float = _opt(50.0, lo=1.0, hi=200.0,
                                doc="Python's thread switch interval, ms: how long the fusing thread "
                                    "keeps the interpreter before the network threads may take it "
                                    "(5 is Python's own; 50 shortens the latency tail under a flood)")


@dataclass(frozen=True)
class LogSection:
    """Field logging to MCAP."""

    dir: str = _opt("", doc="log folder; empty = no logging")
    rotate_mb: float = _opt(512.0, lo=0.0, lo_open=True, doc="start a new file at this size, MB")
    rotate_s: float = _opt(600.0, lo=0.0, lo_open=True, doc="start a new file at this age, s")
    chunk_kb: float = _opt(256.0, lo=0.0, lo_open=True, hi=65536.0, doc="MCAP chunk size, KB")
    flush_s: float = _opt(1.0, lo=0.0, lo_open=True, hi=600.0, doc="close a chunk at least this often")
    compression: str = _opt("zstd", choices=("zstd", "lz4", "none"), doc="chunk compression")
    raw: bool = _opt(True, doc="log raw UART bytes / DCA1000 frames")
    raw_floor_mb: float = _opt(2048.0, lo=0.0, doc="below this free disk, raw data stops")
    floor_mb: float = _opt(512.0, lo=0.0, doc="below this free disk, all logging stops")
    retry_s: float = _opt(30.0, lo=0.0, lo_open=True, hi=3600.0,
                          doc="a failing log disk is tried again after 1 s, doubling up to this, s")
    error_interval_s: float = _opt(60.0, lo=0.0, lo_open=True, hi=86400.0,
                                   doc="while the log disk fails, at most one error line per this, s")


@dataclass(frozen=True)
class AuthSection:
    """Signing keys and the fleet trust file (edge/auth.py); `mmatch keys` makes them."""

    keys: str = _opt("auto", choices=("auto", "dev", "files"),
                     doc="files: key_file and trust_file; dev: keys generated on this machine in "
                         "dev_dir (simulation only, flagged in health); auto: dev for a simulated "
                         "radar or scene files without key_file, else files")
    key_file: str = _opt("", doc="this vehicle's Ed25519 private key (PEM), from `mmatch keys`")
    trust_file: str = _opt("", doc="the fleet's public keys (TOML); re-read on change or SIGHUP")
    dev_dir: str = _opt("", doc="dev keys folder; empty = ~/.cache/mmatch/dev-keys")
    ahead_s: float = _opt(0.05, lo=0.0, hi=10.0,
                          doc="accept stamps at most this far ahead of our clock (clock error), s")
    behind_s: float = _opt(0.15, lo=0.0, lo_open=True, hi=60.0,
                           doc="refuse frames stamped longer ago than this (pairing window + transit), s")


@dataclass(frozen=True)
class HealthSection:
    """systemd integration."""

    watchdog: bool = _opt(True, doc="send WATCHDOG=1 when systemd asks for it")


@dataclass(frozen=True)
class VehicleConfig:
    """The whole vehicle service configuration (cfg/vehicle*.toml)."""

    vehicle: VehicleSection = field(default_factory=VehicleSection)
    radar: RadarSection = field(default_factory=RadarSection)
    camera: CameraSection = field(default_factory=CameraSection)
    sim: SimSection = field(default_factory=SimSection)
    scene: SceneSection = field(default_factory=SceneSection)
    zenoh: ZenohSection = field(default_factory=ZenohSection)
    ego: EgoSection = field(default_factory=EgoSection)
    loop: LoopSection = field(default_factory=LoopSection)
    log: LogSection = field(default_factory=LogSection)
    auth: AuthSection = field(default_factory=AuthSection)
    health: HealthSection = field(default_factory=HealthSection)

    @property
    def is_cav(self) -> bool:
        return self.vehicle.role in ("cav", "both")

    @property
    def is_ego(self) -> bool:
        return self.vehicle.role in ("ego", "both")


# --------------------------------------------------------------------------- loading

def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _check_scalar(value: Any, tp: Any, key: str) -> Any:
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{key}: must be finite, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    raise ConfigError(f"{key}: unsupported type {_type_name(tp)}")  # pragma: no cover


def _check_rules(value: Any, meta: dict, key: str) -> None:
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{key}: {value!r} is not one of {', '.join(map(str, choices))}")
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is not None and (value < lo or (meta.get("lo_open") and value == lo)):
        rel = ">" if meta.get("lo_open") else ">="
        raise ConfigError(f"{key}: {value!r} is impossible, must be {rel} {lo}")
    if hi is not None and value > hi:
        raise ConfigError(f"{key}: {value!r} is impossible, must be <= {hi}")


def _build(cls: type, data: Any, prefix: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix or '<root>'}: expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(names))
    if unknown:
        key = f"{prefix}.{unknown[0]}" if prefix else unknown[0]
        raise ConfigError(f"{key}: unknown key (known: {', '.join(names)})")
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        tp = hints[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key)
            continue
        if typing.get_origin(tp) is list:
            (item_tp,) = typing.get_args(tp)
            if not isinstance(value, list):
                raise ConfigError(f"{key}: expected a list, got {value!r}")
            kwargs[name] = [_check_scalar(v, item_tp, f"{key}[{i}]") for i, v in enumerate(value)]
            continue
        kwargs[name] = _check_scalar(value, tp, key)
        _check_rules(kwargs[name], dict(names[name].metadata), key)
    return cls(**kwargs)


def _cross_checks(cfg: VehicleConfig) -> None:
    """Checks that involve several keys; each error names the key to fix."""
    if not cfg.vehicle.id or any(c in cfg.vehicle.id for c in "/*$?# ") or len(cfg.vehicle.id) > 64:
        raise ConfigError(f"vehicle.id: {cfg.vehicle.id!r} must be 1-64 characters without / * $ ? # or space")
    for i, cav in enumerate(cfg.ego.cavs):
        if not cav or any(c in cav for c in "/*$?# "):
            raise ConfigError(f"ego.cavs[{i}]: {cav!r} is not a vehicle id")
    if cfg.radar.source == "uart" and not cfg.radar.port:
        raise ConfigError("radar.port: required when radar.source = \"uart\"")
    if cfg.radar.source == "dca1000" and not cfg.radar.cfg:
        raise ConfigError("radar.cfg: required when radar.source = \"dca1000\"")
    if cfg.radar.source == "replay" and not cfg.radar.path:
        raise ConfigError("radar.path: required when radar.source = \"replay\"")
    if cfg.radar.source == "scene" and not cfg.scene.path:
        raise ConfigError("scene.path: required when radar.source = \"scene\"")
    if cfg.camera.source == "scene" and cfg.radar.source != "scene":
        raise ConfigError("camera.source: \"scene\" needs radar.source = \"scene\" (the detections come "
                          "with the radar frames)")
    if cfg.camera.source == "replay" and not cfg.camera.path:
        raise ConfigError("camera.path: required when camera.source = \"replay\"")
    if cfg.camera.source in ("opencv", "oak") and not cfg.camera.calibration:
        raise ConfigError(f"camera.calibration: required when camera.source = \"{cfg.camera.source}\"")
    if cfg.zenoh.mode == "client" and not cfg.zenoh.connect:
        raise ConfigError("zenoh.connect: client mode needs at least one router endpoint")
    z = cfg.zenoh
    tls = [k for k in ("tls_root_ca", "tls_certificate", "tls_private_key") if getattr(z, k)]
    if tls and len(tls) != 3:
        missing = next(k for k in ("tls_root_ca", "tls_certificate", "tls_private_key") if k not in tls)
        raise ConfigError(f"zenoh.{missing}: mutual TLS needs the CA, the certificate and the key")
    for key in ("listen", "connect"):
        for i, ep in enumerate(getattr(cfg.zenoh, key)):
            if "/" not in ep:
                raise ConfigError(f"zenoh.{key}[{i}]: {ep!r} is not an endpoint like tcp/127.0.0.1:7447")
            if tls and not ep.startswith("tls/"):
                raise ConfigError(f"zenoh.{key}[{i}]: {ep!r} with mutual TLS configured: use tls/HOST:PORT")
    if cfg.log.floor_mb > cfg.log.raw_floor_mb:
        raise ConfigError("log.floor_mb: must be <= log.raw_floor_mb (raw data stops first)")
    if cfg.auth.behind_s < cfg.ego.pair_tolerance_s:
        raise ConfigError("auth.behind_s: must be >= ego.pair_tolerance_s (frames that could still pair)")
    if cfg.sim.phase_s >= 1.0 / cfg.sim.rate_hz:
        raise ConfigError("sim.phase_s: must be shorter than one frame period (1 / sim.rate_hz)")


def auth_mode(cfg: VehicleConfig) -> str:
    """"dev" or "files": how this vehicle gets its keys (AuthSection.keys resolved)."""
    if cfg.auth.keys != "auto":
        return cfg.auth.keys
    return "dev" if cfg.radar.source in ("sim", "scene") and not cfg.auth.key_file else "files"


def from_dict(data: dict, *, source: str = "<dict>") -> VehicleConfig:
    """Build and check a config from a parsed TOML table; errors name the key."""
    try:
        cfg = _build(VehicleConfig, data, "")
        _cross_checks(cfg)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return cfg


def read_table(path: str | Path) -> dict:
    """The TOML table of a config file; ConfigError naming the path for a missing file, a
    folder, a file that is not UTF-8 or not TOML, and an empty one."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a folder, not a config file (e.g. cfg/vehicle.toml)")
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: no such file") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason}); "
                          "a config is a TOML file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if not data:
        raise ConfigError(f"{path}: the config is empty (at least [vehicle] id and role; "
                          "`mmatch config --example cav` prints one)")
    return data


def load(path: str | Path, overrides: dict | None = None) -> VehicleConfig:
    """Load a TOML file; `overrides` is a nested dict merged on top (from the CLI)."""
    data = read_table(path)
    if overrides:
        data = merge(data, overrides)
    return from_dict(data, source=str(path))


def parse_overrides(items: list[str]) -> dict:
    """["a.b=1", "c.d=x"] -> {"a": {"b": 1}, "c": {"d": "x"}} (TOML values, else strings)."""
    out: dict = {}
    for item in items:
        key, sep, raw = item.partition("=")
        parts = key.strip().split(".")
        if not sep or len(parts) != 2 or not all(parts):
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        out.setdefault(parts[0], {})[parts[1]] = value
    return out


def merge(base: dict, top: dict) -> dict:
    """Nested dict merge (top wins), new dicts, inputs untouched."""
    out = dict(base)
    for k, v in top.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


def to_dict(cfg: Any) -> dict:
    """The effective config as plain nested dicts."""
    return dataclasses.asdict(cfg)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")  # pragma: no cover


def to_toml(cfg: VehicleConfig) -> str:
    """The effective config as TOML text; `load` of it gives an equal config."""
    lines = ["# effective mmatch vehicle config (defaults + file)"]
    for section, values in to_dict(cfg).items():
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


def log_effective(cfg: VehicleConfig) -> None:
    """Log the effective config at INFO, one line per section."""
    for section, values in to_dict(cfg).items():
        log.info("config [%s] %s", section, " ".join(f"{k}={v!r}" for k, v in values.items()))
