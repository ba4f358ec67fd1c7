"""`mmatch sim`: simulate Ego/CAV scene pairs and print how hard they are."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mmatch.edge.commands.args import positive_int, unit_interval

HELP = "simulate mmatch-scene/1 files (easy, hard or mixed; independent scenes or sequences) and print their realism figures"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output folder (created; must not be a file)")
    p.add_argument("--n", type=positive_int, default=200, help="number of scene pairs")
    p.add_argument("--seed", type=int, default=0, help="random seed of the first scene")
    p.add_argument("--mode", choices=["easy", "hard", "mixed"], default="mixed", help="difficulty")
    p.add_argument("--physics", default="nominal",
                   help="nominal (central constants), wide (each unknown constant drawn per scene from its "
                        "documented range) or a TOML file of ranges (see mmatch/sim/physics.py)")
    p.add_argument("--jobs", type=positive_int, default=1, help="worker processes")
    p.add_argument("--sequences", type=positive_int, default=None, metavar="S",
                   help="write S sequences (drives of one world each, DESIGN.md 'Sequences') instead of --n "
                        "independent scenes; the physics is drawn once per sequence")
    p.add_argument("--frames", type=positive_int, default=60, metavar="F",
                   help="frames per sequence (20 Hz) with --sequences")
    p.add_argument("--vehicles", default=None, metavar="LO-HI",
                   help="dense traffic: LO-HI other vehicles per scene (default: 1-4 easy, 6-20 hard)")
    p.add_argument("--junction", default=None, metavar="LO-HI",
                   help="angle between the crossing roads of a junction drawn from LO-HI deg (45-135; "
                        "default: 90), for independent scenes and sequences alike")
    p.add_argument("--stopped", type=unit_interval, default=None, metavar="SHARE",
                   help="share of scenes (0-1) in which the Ego or the CAV stands still (its velocity gives "
                        "no road direction; default 0); a world the scenario keeps is the seed's, stopped")


def run(args: argparse.Namespace) -> int:
    from mmatch.edge.commands.progress import Progress
    from mmatch.sim.generate import generate
    from mmatch.errors import ConfigError
    from mmatch.sim.world import junction_override, stopped_override, traffic_override

    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise ConfigError(f"--out {args.out}: exists and is not a folder")
    if args.sequences is not None:
        return _run_sequences(args)
    with traffic_override(_vehicle_range(args.vehicles)), stopped_override(args.stopped), \
            junction_override(_junction_range(args.junction)):
        scenes = generate(args.out, args.n, args.seed, args.mode, args.jobs, Progress("sim"), physics=args.physics)
    print(f"wrote {len(scenes)} scenes ({args.mode}, physics {args.physics}, seed {args.seed}) to {args.out}")
    if args.stopped:
        who = [s.meta.get("stopped", "") for s in scenes]
        print(f"  standing still: the Ego in {who.count('ego')}, the CAV in {who.count('cav')} scenes")
    _print_realism(scenes, args.out)
    return 0


def _run_sequences(args: argparse.Namespace) -> int:
    import numpy as np

    from mmatch.edge.commands.progress import Progress
    from mmatch.errors import ConfigError
    from mmatch.sim.generate import generate_sequences

    if args.vehicles is not None:
        raise ConfigError("--vehicles: not available with --sequences (a drive draws its own traffic)")
    if args.stopped is not None:
        raise ConfigError("--stopped: not available with --sequences (a drive draws its own traffic)")
    from mmatch.sim.world import junction_override

    with junction_override(_junction_range(args.junction)):
        scenes = generate_sequences(args.out, args.sequences, args.frames, args.seed, args.mode, args.jobs,
                                    Progress("sim"), physics=args.physics)
    print(f"wrote {args.sequences} sequences of {args.frames} frames ({len(scenes)} scenes; {args.mode}, "
          f"physics {args.physics}, seed {args.seed}) to {args.out}")
    firsts = [s.meta for s in scenes if s.meta["frame"] == 0]
    cov = np.array([s.meta["covisible"] for s in scenes])
    print(f"  frames with 0 / 1 / 2+ co-visible vehicles: {np.mean(cov == 0):.3f} / {np.mean(cov == 1):.3f} / "
          f"{np.mean(cov >= 2):.3f}")
    print(f"  sequences at a junction {np.mean([m['road'] != 'straight' for m in firsts]):.2f}, CAV turning "
          f"{np.mean([m['cav_turns'] for m in firsts]):.2f}, oncoming CAV "
          f"{np.mean([m['relation'] == 'opposite' for m in firsts]):.2f}, truck overtaking "
          f"{np.mean([m['truck'] for m in firsts]):.2f}, light traffic {np.mean([m['light_traffic'] for m in firsts]):.2f}")
    print("  (the realism targets below are those of independent scenes)")
    _print_realism(scenes, args.out)
    return 0


def _print_realism(scenes: list, out: str) -> None:
    import json
    from pathlib import Path

    from mmatch.sim.realism import check_targets, realism_figures

    fig = realism_figures(scenes)
    ok = check_targets(fig)
    print("realism (from the ground-truth labels):")
    for key, value in fig.items():
        mark = "" if key not in ok else ("  ok" if ok[key] else "  OUT OF TARGET")
        print(f"  {key:<40} {value:.3f}{mark}" if isinstance(value, float) else f"  {key:<40} {value}")
    (Path(out) / "realism.json").write_text(json.dumps({"figures": fig, "within_target": ok}, indent=2))


def _junction_range(text: str | None) -> tuple[float, float] | None:
    from mmatch.sim.world import parse_range
    return None if text is None else parse_range(text, "--junction", 45, 135)


def _vehicle_range(text: str | None) -> tuple[int, int] | None:
    from mmatch.sim.world import parse_range
    return None if text is None else parse_range(text, "--vehicles", 0, 1000, int)
