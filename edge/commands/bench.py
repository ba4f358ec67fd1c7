"""`mmatch bench`: speed benchmarks of every hot path, written to a results folder."""

from __future__ import annotations

import argparse
import importlib
import json
import time
from pathlib import Path

HELP = "run the speed benchmarks (UART reader, DSP, camera, pipeline) and write a JSON report"

# name -> "module:function"; each function takes (quick: bool) and returns a flat dict of numbers.
SUITES: dict[str, str] = {
    "uart": "mmatch.drivers.ti.bench:run",
    "dsp": "mmatch.drivers.dca1000.bench:run",
    "camera": "mmatch.drivers.camera.bench:run",
    "pipeline": "mmatch.bench:run",
    "edge": "mmatch.edge.bench:run",
    "rmnet": "mmatch.ego.match.bench:run",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench-results", help="folder for bench.json")
    p.add_argument("--only", nargs="*", choices=sorted(SUITES), help="run only these suites")
    p.add_argument("--quick", action="store_true", help="short smoke version (for tests)")


def run(args: argparse.Namespace) -> int:
    results: dict[str, dict] = {}
    for name in args.only or SUITES:
        module_name, func = SUITES[name].split(":")
        try:
            fn = getattr(importlib.import_module(module_name), func)
        except ModuleNotFoundError as exc:
            results[name] = {"error": f"not available: {exc}"}
            continue
        t0 = time.perf_counter()
        results[name] = fn(quick=args.quick)
        results[name]["wall_s"] = round(time.perf_counter() - t0, 3)
        print(f"[{name}]")
        for key, value in results[name].items():
            print(f"  {key:<40} {value}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {out / 'bench.json'}")
    return 0
