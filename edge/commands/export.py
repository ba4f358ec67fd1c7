"""`mmatch export --ros2 LOG OUT`: a field log as a ROS 2 bag (edge/ros2.py)."""

from __future__ import annotations

import argparse
import json

HELP = "export a field log (MCAP file or folder) as a ROS 2 bag: PointCloud2, TFMessage, MarkerArray"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ros2", nargs=2, metavar=("LOG", "OUT"), required=True,
                   help="the log (file or folder) and the bag folder to create")
    p.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                   help="bag storage: sqlite3 (as ROS 2 Humble records) or mcap (as Jazzy records)")
    p.add_argument("--json", metavar="FILE", help="also write the summary here")


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.ros2 import export_ros2

    log_path, out = args.ros2
    summary = export_ros2(log_path, out, storage=args.storage)
    for topic, info in summary["topics"].items():
        print(f"  {topic:<32} {info['type']:<38} {info['messages']}")
    if summary["skipped"]:
        print("  left out: " + ", ".join(f"{t} ({n})" for t, n in summary["skipped"].items()))
    print(f"wrote {summary['bag']} ({summary['storage']})")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary, f, indent=1)
    return 0
