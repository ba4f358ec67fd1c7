"""`mmatch record --config cfg/vehicle.toml`: log the sensors only (no processing, no Zenoh)."""

from __future__ import annotations

import argparse

from mmatch.edge.commands.run import add_common

HELP = "record sensors only (raw UART/DCA1000 data, points, detections) to MCAP"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_common(p)


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.commands.run import service_main

    return service_main(args, process=False, need_log=True)
