"""`mmatch radar-info`: what a TI .cfg means (range, velocity, resolution, timing)."""

from __future__ import annotations

import argparse
import json
import logging

HELP = "parse a TI radar .cfg and print its range/velocity limits and resolutions"

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cfg", required=True, help="TI CLI .cfg file")
    p.add_argument("--json", metavar="OUT", help="also write the chirp parameters as JSON")
    p.add_argument("--min-velocity", type=float, default=None,
                   help="warn below this max velocity, m/s (default: 20, vehicles)")


def run(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from mmatch.drivers.ti.cfg import VEHICLE_MIN_VELOCITY_MPS, load_cfg, vehicle_warnings

    cfg = load_cfg(args.cfg)
    c = cfg.chirp
    need = VEHICLE_MIN_VELOCITY_MPS if args.min_velocity is None else args.min_velocity
    warnings = vehicle_warnings(c, min_velocity_mps=need)
    rows = [
        ("start frequency", f"{c.start_freq_ghz:g} GHz"),
        ("TX x RX", f"{c.num_tx} x {c.num_rx} (TX order per loop {list(c.tx_order)}, "
                    f"masks tx {c.tx_mask:#x} rx {c.rx_mask:#x})"),
        ("chirp", f"Tc {c.chirp_time_us:g} us (idle {c.idle_time_us:g} + ramp {c.ramp_end_time_us:g}), "
                  f"slope {c.slope_mhz_per_us:g} MHz/us, {c.num_adc_samples} samples at "
                  f"{c.sample_rate_ksps:g} ksps, bandwidth {c.bandwidth_mhz:.1f} MHz"),
        ("frame", f"{c.num_loops} loops, {c.chirps_per_frame} chirps, period {c.frame_period_ms:g} ms "
                  f"({1000.0 / c.frame_period_ms:.1f} Hz)"),
        ("range", f"max {c.max_range_m:.2f} m, resolution {c.range_resolution_m:.4f} m, "
                  f"bin {c.range_idx_to_m:.4f} m x {c.num_range_bins} bins"),
        ("velocity", f"max +-{c.max_velocity_mps:.2f} m/s, resolution {c.doppler_resolution_mps:.4f} m/s, "
                     f"{c.num_doppler_bins} Doppler bins"),
    ]
    print(f"{cfg.path}: {len(cfg.commands)} commands")
    for name, value in rows:
        print(f"  {name:<16} {value}")
    for w in warnings:
        print(f"  WARNING: {w}")
    if args.json:
        doc = asdict(c)
        doc["tx_order"] = list(c.tx_order)
        doc["warnings"] = warnings
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=1)
        print(f"wrote {args.json}")
    return 0
