"""`mmatch radar-config`: send a .cfg to a TI radar over its CLI port."""

from __future__ import annotations

import argparse
import logging

HELP = "configure a TI radar: send a .cfg line by line over the CLI port (115200 baud)"

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="CLI port (e.g. /dev/ttyACM0, COM3, or a pyserial URL)")
    p.add_argument("--cfg", required=True, help="TI CLI .cfg file (validated before anything is sent)")
    p.add_argument("--baud", type=int, default=115200, help="CLI baud rate (default 115200)")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for each answer")


def run(args: argparse.Namespace) -> int:
    from drivers.ti.cfg import load_cfg
    from drivers.ti.config_sender import send_cfg

    cfg = load_cfg(args.cfg)  # refuses a bad cfg, naming the line, before the port is opened
    for w in cfg.warnings:
        print(f"WARNING: {w}")
    replies = send_cfg(args.port, cfg, baudrate=args.baud, timeout_s=args.timeout,
                       on_reply=lambda r: print(f"  {r.lineno:>3}  {r.line}"))
    c = cfg.chirp
    print(f"{args.port}: {len(replies)} commands accepted; max range {c.max_range_m:.1f} m, "
          f"max velocity +-{c.max_velocity_mps:.1f} m/s, {1000.0 / c.frame_period_ms:.1f} frames/s")
    return 0
