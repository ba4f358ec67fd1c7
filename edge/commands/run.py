"""`mmatch run --config cfg/vehicle.toml`: the vehicle service (CAV, Ego or both)."""

from __future__ import annotations

import argparse
import logging
import sys

HELP = "run the vehicle service: sensors -> CAV/Ego loop -> Zenoh, with field logging"

log = logging.getLogger(__name__)


def add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", "-c", required=True, help="vehicle config (TOML), e.g. cfg/vehicle.toml or cfg/vehicle-cav-sim.toml")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one config value (TOML syntax for the value; repeatable)")
    p.add_argument("--log-dir", help="shorthand for --set log.dir=DIR")
    p.add_argument("--duration", type=float, help="stop after this many seconds")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_common(p)


def parse_overrides(items: list[str]) -> dict:
    """--set items as a nested dict (see edge.config.parse_overrides)."""
    from mmatch.edge.config import parse_overrides as parse

    return parse(items)


def service_logging(args: argparse.Namespace) -> None:
    """A service shows its effective config, status lines and summaries without -v
    (the journal is its log); -v/-vv still go further."""
    if getattr(args, "verbose", 0) == 0:
        logging.getLogger("mmatch.edge").setLevel(logging.INFO)


def load_config(args: argparse.Namespace, extra: dict | None = None):
    from mmatch.edge import config

    service_logging(args)

    overrides = parse_overrides(args.set)
    if getattr(args, "log_dir", None):
        overrides.setdefault("log", {})["dir"] = args.log_dir
    if extra:
        overrides = config.merge(overrides, extra)
    cfg = config.load(args.config, overrides)
    config.log_effective(cfg)
    return cfg


def run_service(cfg, *, duration: float | None = None, process: bool = True) -> int:
    """Open everything the config names, run the loop until SIGTERM/SIGINT/duration, close."""
    import contextlib
    import signal
    import threading

    from mmatch.edge import config as config_mod
    from mmatch.edge.auth import identity as make_identity
    from mmatch.edge.health import Notifier
    from mmatch.edge.loop import VehicleLoop
    from mmatch.edge.pipeline import default_pipeline
    from mmatch.edge.recorder import Recorder
    from mmatch.edge.sources import open_camera, open_radar
    from mmatch.edge.transport import Transport

    # the fusing thread keeps the interpreter for gil_switch_ms: with 1000 rejected frames/s on
    # the network threads (tests/edge/test_edge_flood.py, 2 cores shared with the CAV and the
    # attacker), Python's 5 ms gave a median latency of 18 ms and p99 80 ms over 8 runs, 50 ms
    # gave 15 ms and 58 ms over 9 (the spread of both is wide: p99 33-152 and 37-131 ms)
    sys.setswitchinterval(cfg.loop.gil_switch_ms / 1e3)
    pipeline = default_pipeline(need_fuse=cfg.is_ego, track_max_age_s=cfg.ego.track_max_age_s,
                                    confidence_threshold=cfg.ego.confidence_threshold) if process else None
    ident = make_identity(cfg) if process else None
    notifier = Notifier()
    with contextlib.ExitStack() as stack:
        # the recorder opens last and closes first: a log never waits on a sensor or on Zenoh
        # (systemd's TimeoutStopSec covers Recorder.CLOSE_TIMEOUT_S and the readers' joins)
        transport = stack.enter_context(Transport(cfg.zenoh)) if process else None
        radar = open_radar(cfg)
        stack.callback(radar.close)
        camera = open_camera(cfg, radar=radar)
        stack.callback(camera.close)
        stack.callback(notifier.close)
        recorder = None
        if cfg.log.dir:
            recorder = stack.enter_context(Recorder(cfg.log, prefix=f"{cfg.vehicle.id}",
                                                    config_text=config_mod.to_toml(cfg)))
        loop = VehicleLoop(cfg, radar, camera, pipeline, transport=transport, recorder=recorder,
                           notifier=notifier, process=process, identity=ident)

        def on_signal(signum: int, _frame: object) -> None:
            log.info("signal %d: stopping", signum)
            loop.stop.set()

        def on_hangup(signum: int, _frame: object) -> None:
            if ident is not None and ident.trust is not None:
                ident.trust.request_reload()

        old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
        old[signal.SIGHUP] = signal.signal(signal.SIGHUP, on_hangup)
        stack.callback(lambda: [signal.signal(s, h) for s, h in old.items()])
        if duration is not None:
            timer = threading.Timer(duration, loop.stop.set)
            timer.daemon = True
            timer.start()
            stack.callback(timer.cancel)
        rc = loop.run()
        if loop.node is not None:
            log.info("summary: %s", loop.node.summary())
    return rc


#: exit status of a configuration error: systemd does not restart on it
#: (RestartPreventExitStatus= in systemd/mmatch-edge.service); EX_CONFIG of sysexits.h
EXIT_CONFIG = 78


def service_main(args: argparse.Namespace, *, process: bool = True, need_log: bool = False) -> int:
    """Load the config and run the service; a ConfigError (at load or while opening what the
    config names) exits with EXIT_CONFIG."""
    from mmatch.errors import ConfigError

    try:
        cfg = load_config(args)
        if need_log and not cfg.log.dir:
            raise ConfigError("log.dir: recording needs a log folder (--log-dir DIR)")
        return run_service(cfg, duration=args.duration, process=process)
    except ConfigError as exc:
        exc.exit_code = EXIT_CONFIG
        raise


def run(args: argparse.Namespace) -> int:
    return service_main(args)
