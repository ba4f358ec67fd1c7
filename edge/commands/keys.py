"""`mmatch keys --out DIR cav1 ego1 ...`: the fleet's signing keys, trust file and TLS certificates."""

from __future__ import annotations

import argparse

HELP = "make the fleet's Ed25519 signing keys, the trust file, and (--tls) a CA with per-vehicle certificates"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("vehicles", nargs="*", help="vehicle ids; a vehicle that has a key keeps it")
    p.add_argument("--out", required=True, help="fleet folder: <id>.key, trust.toml, tls/")
    p.add_argument("--rotate", action="append", default=[], metavar="ID",
                   help="give ID a new key; the trust file keeps the old one too until --retire")
    p.add_argument("--retire", action="append", default=[], metavar="ID",
                   help="drop every key of ID but its current one from the trust file")
    p.add_argument("--tls", action="store_true",
                   help="also a fleet CA and a TLS certificate per vehicle (and --router) for Zenoh mTLS")
    p.add_argument("--router", action="append", default=[], metavar="NAME",
                   help="with --tls: a certificate for a router (its DNS name or IP address)")
    p.add_argument("--days", type=int, default=365, help="certificate lifetime (default 365 days)")


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.fleet import make_fleet

    report = make_fleet(args.out, args.vehicles, rotate=args.rotate, retire=args.retire,
                        tls=args.tls, routers=args.router, days=args.days)
    for line in report:
        print(line)
    return 0
