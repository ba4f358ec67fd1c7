"""`mmatch record --config cfg/vehicle.toml`: log the sensors only (no processing, no Zenoh)."""

from __future__ import annotations

import argparse

from mmatch.edge.commands.run import add_common

HELP = "record sensors only (raw UART/DCA1000 data, points, detections) to MCAP"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_common(p)


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.commands.run import load_config, run_service
    from mmatch.errors import ConfigError

    cfg = load_config(args)
    if not cfg.log.dir:
        raise ConfigError("log.dir: recording needs a log folder (--log-dir DIR)")
    return run_service(cfg, duration=args.duration, process=False)
