"""`mmatch parse-uart`: decode a raw TI UART capture and summarise it."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from mmatch.edge.commands.output import write_json

HELP = "decode a raw TI UART (TLV) capture: frames, points, skipped bytes, rejects by reason"

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="raw capture of the data port (bytes as they came over the UART)")
    p.add_argument("--json", metavar="OUT", help="write the summary as JSON here")
    p.add_argument("--cfg", help="the .cfg the radar ran (scales SDK 1.x/2.x Doppler indices)")
    p.add_argument("--on-error", choices=("skip", "log", "raise"), default="skip",
                   help="bad-input policy of the reader (default: skip, counted in the summary)")


def summarise(path: str | Path, *, cfg: str | None = None, on_error: str = "skip") -> dict:
    """The `--json` document: {"frames", "frame_numbers", "points_per_frame", "bytes_skipped",
    "rejected": [{"offset", "reason"}], "tlv_types": {"<type>": n}, "first_point": {...}|None}
    plus, under "_stats", the reader counters (not written to the JSON)."""
    from mmatch.drivers.ti.cfg import load_cfg
    from mmatch.drivers.ti.reader import TlvReader
    from mmatch.drivers.ti.sources import FileSource

    chirp = load_cfg(cfg).chirp if cfg else None
    frame_numbers: list[int] = []
    points_per_frame: list[int] = []
    first_point = None
    with FileSource(path) as src:
        reader = TlvReader(src, on_error=on_error, chirp=chirp, keep=10**7)
        for pkt in reader.packets():
            frame_numbers.append(pkt.header.frame_number)
            points_per_frame.append(len(pkt.points))
            if first_point is None and len(pkt.points):
                x, y, z, d, s = (float(v) for v in pkt.points[0])
                first_point = {"x": x, "y": y, "z": z, "doppler": d, "snr": s}
    st = reader.stats
    return {
        "frames": st.frames,
        "frame_numbers": frame_numbers,
        "points_per_frame": points_per_frame,
        "bytes_skipped": st.bytes_skipped,
        "rejected": [{"offset": off, "reason": why} for off, why in st.rejections],
        "tlv_types": {str(k): v for k, v in sorted(st.tlv_types.items())},
        "first_point": first_point,
        "_stats": st,
    }


def run(args: argparse.Namespace) -> int:
    summary = summarise(args.file, cfg=args.cfg, on_error=args.on_error)
    st = summary.pop("_stats")
    n = summary["frames"]
    ppf = summary["points_per_frame"]
    fns = summary["frame_numbers"]
    print(f"{args.file}: {st.bytes_in} bytes, {n} frames accepted"
          + (f" (frame numbers: first {fns[0]}, last {fns[-1]})" if fns else ""))
    print(f"  formats: {dict(st.formats) or '-'}")
    if ppf:
        print(f"  points per frame: min {min(ppf)}, mean {sum(ppf) / len(ppf):.1f}, max {max(ppf)}, "
              f"total {sum(ppf)}")
    print(f"  bytes skipped: {st.bytes_skipped}")
    print(f"  frames rejected: {st.rejected_total}"
          + (" (" + ", ".join(f"{k} {v}" for k, v in sorted(st.rejected.items())) + ")"
             if st.rejected else ""))
    print(f"  sensor restarts: {st.restarts}, missing frame numbers: {st.frame_gaps}")
    print(f"  TLV types: {summary['tlv_types'] or '-'} (kept raw: {st.unknown_tlvs} unknown, "
          f"{st.malformed_tlvs} of an unexpected size)")
    if summary["first_point"]:
        fp = summary["first_point"]
        print("  first point: " + ", ".join(f"{k} {v:.3f}" for k, v in fp.items()))
    if args.json:
        write_json(args.json, summary, indent=1)
    return 0
