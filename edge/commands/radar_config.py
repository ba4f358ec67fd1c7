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
    p.add_argument("--data-port", help="after configuring, check that frames arrive on this data port")
    p.add_argument("--data-baud", type=int, default=921600, help="data port baud rate (default 921600)")
    p.add_argument("--check-s", type=float, default=3.0, help="seconds to listen on --data-port")


def run(args: argparse.Namespace) -> int:
    from mmatch.drivers.ti.cfg import load_cfg
    from mmatch.drivers.ti.config_sender import send_cfg

    cfg = load_cfg(args.cfg)  # refuses a bad cfg, naming the line, before the port is opened
    for w in cfg.warnings:
        print(f"WARNING: {w}")
    replies = send_cfg(args.port, cfg, baudrate=args.baud, timeout_s=args.timeout,
                       on_reply=lambda r: print(f"  {r.lineno:>3}  {r.line}"))
    c = cfg.chirp
    print(f"{args.port}: {len(replies)} commands accepted; max range {c.max_range_m:.1f} m, "
          f"max velocity +-{c.max_velocity_mps:.1f} m/s, {1000.0 / c.frame_period_ms:.1f} frames/s")
    if args.data_port:
        check_data_port(args.data_port, args.data_baud, args.check_s, chirp=c)
    return 0


def check_data_port(port: str, baud: int, seconds: float, chirp=None) -> dict:  # noqa: ANN001
    """Listen on the data port; print frames/s and skipped bytes; DeviceTimeout if no frame."""
    import time

    from mmatch.drivers.ti.reader import TlvReader
    from mmatch.drivers.ti.sources import SerialSource
    from mmatch.errors import DeviceTimeout

    with SerialSource(port, baudrate=baud, timeout=0.05) as src:
        reader = TlvReader(src, on_error="skip", chirp=chirp)
        t0 = time.monotonic()
        points = 0
        while time.monotonic() - t0 < seconds:
            frame = reader.read_frame(timeout=max(0.0, seconds - (time.monotonic() - t0)))
            if frame is not None:
                points += len(frame.points)
        elapsed = time.monotonic() - t0
    st = reader.stats
    print(f"{port}: {st.frames} frames in {elapsed:.1f} s ({st.frames / elapsed:.1f}/s), "
          f"{points} points, {st.bytes_in} bytes, {st.bytes_skipped} skipped, "
          f"{st.rejected_total} frames rejected")
    if st.frames == 0:
        hint = ("bytes but no frame: wrong baud rate (data port runs at 921600) or the CLI port?"
                if st.bytes_in else "no bytes at all: wrong port, or the sensor did not start")
        raise DeviceTimeout(f"{port}: no radar frame within {seconds:g} s; {hint}")
    return st.as_dict()
