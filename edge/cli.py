"""The `mmatch` command line: a thin dispatcher over `mmatch.edge.commands.*`."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from mmatch.edge.commands.args import DefaultsFormatter
from mmatch.errors import MMatchError

COMMANDS: dict[str, str] = {
    "sim": "mmatch.edge.commands.sim",
    "eval": "mmatch.edge.commands.evaluate",
    "report": "mmatch.edge.commands.report",
    "demo": "mmatch.edge.commands.demo",
    "egomotion": "mmatch.edge.commands.egomotion",
    "bench": "mmatch.edge.commands.bench",
    "parse-uart": "mmatch.edge.commands.parse_uart",
    "radar-config": "mmatch.edge.commands.radar_config",
    "radar-info": "mmatch.edge.commands.radar_info",
    "dsp": "mmatch.edge.commands.dsp",
    "run": "mmatch.edge.commands.run",
    "replay": "mmatch.edge.commands.replay",
    "record": "mmatch.edge.commands.record",
    "fit-confidence": "mmatch.edge.commands.fit_confidence",
    "fit-separation": "mmatch.edge.commands.fit_separation",
    "config": "mmatch.edge.commands.config",
    "router": "mmatch.edge.commands.router",
    "export": "mmatch.edge.commands.export",
    "keys": "mmatch.edge.commands.keys",
    "train": "mmatch.edge.commands.train",
    "ablation": "mmatch.edge.commands.ablation",
    "transfer": "mmatch.edge.commands.transfer",
    "compare": "mmatch.edge.commands.compare",
}


def _quiet_network_libraries() -> None:
    """depthai phones home on import unless told not to (LIBRARIES.md section 3)."""
    os.environ.setdefault("DEPTHAI_TELEMETRY", "0")
    os.environ.setdefault("DEPTHAI_PROTOCOL", "usb")
    os.environ.setdefault("DEPTHAI_DISABLE_STARTUP_NOTIFICATIONS", "1")


def version() -> str:
    """The installed package's version (the source tree's when not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("mmatch")
    except PackageNotFoundError:
        from mmatch import __version__

        return __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mmatch", description=__doc__, formatter_class=DefaultsFormatter)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv: debug)")
    parser.add_argument("--version", action="version", version=f"mmatch {version()}")
    # -v also works after the sub-command (`mmatch run -c FILE -v`); SUPPRESS keeps the
    # top-level count when it is not given there
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                        help="more logging (-vv: debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module_name in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue
        p = sub.add_parser(name, help=module.HELP, description=module.HELP, parents=[common],
                           formatter_class=DefaultsFormatter)
        module.add_arguments(p)
        p.set_defaults(_run=module.run, _parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    _quiet_network_libraries()
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # the sub-command's own usage, not the top-level one
        args._parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args._run(args) or 0)
    except MMatchError as exc:
        print(f"mmatch {args.command}: error: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", 2)  # run/record: 78 for a config error (systemd)
    except OSError as exc:  # an output path that is a file, a full disk, no permission
        print(f"mmatch {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
