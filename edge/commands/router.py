"""`mmatch router`: a Zenoh router from the Python binding, for fleets and roadside units.

Vehicles then run `zenoh.mode = "client"` with `zenoh.connect = ["tcp/<router>:7447"]`.
The same settings as every MMatch session are imposed (no multicast scouting, no gossip,
no shared memory, explicit endpoints); `--config` starts from a zenoh JSON5 file such as
cfg/zenoh/router.json5. zenohd, Eclipse Zenoh's own router, does the same job
(docs/prerequisites.md says where to get it).
"""

from __future__ import annotations

import argparse
import logging

HELP = "run a Zenoh router (the Python binding's router mode) until stopped"

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on, repeatable; in the field the V2X interface's address, "
                        "e.g. tcp/192.168.50.1:7447 (default: tcp/127.0.0.1:7447)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another router to connect to (repeatable)")
    p.add_argument("--config", metavar="FILE", help="zenoh JSON5 file to start from (cfg/zenoh/router.json5)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")


def run(args: argparse.Namespace) -> int:
    import signal
    import threading

    import zenoh

    from mmatch.edge.config import ZenohSection
    from mmatch.edge.health import Notifier
    from mmatch.edge.transport import make_zenoh_config
    from mmatch.errors import ConfigError, DeviceError

    listen = args.listen or ["tcp/127.0.0.1:7447"]
    for ep in [*listen, *args.connect]:
        if "/" not in ep:
            raise ConfigError(f"{ep!r} is not an endpoint like tcp/127.0.0.1:7447")
    section = ZenohSection(mode="router", listen=listen, connect=list(args.connect),
                           config_file=args.config or "")
    conf = make_zenoh_config(section)
    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGTERM, signal.SIGINT)}
    notifier = Notifier()
    try:
        try:
            session = zenoh.open(conf)
        except Exception as exc:  # zenoh raises ZError for a port in use or a bad endpoint
            raise DeviceError(f"zenoh router: cannot start on {', '.join(listen)}: {exc}") from exc
        with session:
            print(f"zenoh router {session.info.zid()} listening on {', '.join(listen)}"
                  + (f", connected to {', '.join(args.connect)}" if args.connect else ""), flush=True)
            notifier.ready("router running")
            stop.wait(args.duration)
            notifier.stopping()
        print("zenoh router stopped", flush=True)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        notifier.close()
    return 0
