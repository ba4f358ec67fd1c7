"""`mmatch config`: example configs and shipped files, config checks, generated docs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "write an example vehicle config (--example ego|cav), copy a shipped file, check a config"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mmatch.edge.resources import EXAMPLES

    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--example", choices=sorted(EXAMPLES),
                      help="write a working example: ego, cav (two simulated vehicles on 127.0.0.1), "
                           "field, field-ego (real sensors, to edit)")
    what.add_argument("--get", metavar="NAME",
                      help="write a shipped file, e.g. radar/xwr68xx_vehicle_100m.cfg or "
                           "systemd/mmatch-edge.service (see --list)")
    what.add_argument("--list", action="store_true", help="list the shipped files")
    what.add_argument("--check", metavar="FILE", help="load a vehicle config and print it as effective")
    what.add_argument("--docs", metavar="DIR", help="write the generated reference pages (docs/)")
    p.add_argument("--out", metavar="PATH",
                   help="where to write (--example, --get; default: the file's own name here; - = stdout)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="with --check: override one config value (repeatable)")


def _write(text: str, default_name: str, out: str | None, force: bool) -> Path | None:
    from mmatch.errors import ConfigError

    if out == "-":
        sys.stdout.write(text)
        return None
    path = Path(out or default_name)
    if path.is_dir():
        path = path / default_name
    if path.exists() and not force:
        raise ConfigError(f"{path}: exists (--force overwrites it)")
    path.write_text(text)
    return path


def run(args: argparse.Namespace) -> int:
    from mmatch.edge import config, docgen, resources

    if args.list:
        for name in resources.shipped_files():
            print(name)
        return 0
    if args.docs:
        for path in docgen.write_docs(args.docs):
            print(f"wrote {path}")
        return 0
    if args.check:
        cfg = config.load(args.check, config.parse_overrides(args.set))
        sys.stdout.write(config.to_toml(cfg))
        return 0
    name = resources.EXAMPLES[args.example] if args.example else args.get
    text = resources.read_shipped(name)
    path = _write(text, Path(name).name, args.out, args.force)
    if path is not None:
        print(f"wrote {path}")
        if args.example in ("ego", "cav"):
            other = "cav" if args.example == "ego" else "ego"
            print(f"run it: mmatch run -c {path}   (with `mmatch config --example {other}` running "
                  "beside it: two simulated vehicles over Zenoh on 127.0.0.1)")
        elif args.example:
            print(f"edit it (vehicle.id, ports, Zenoh endpoints), then: mmatch config --check {path}")
    return 0
