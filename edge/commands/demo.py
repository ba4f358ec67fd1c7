"""`mmatch demo`: simulate a small mixed set, evaluate it, print the table, draw one scene."""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

from mmatch.edge.commands.args import positive_int

HELP = "simulate a small mixed data set, evaluate it and draw a bird's-eye picture (make demo)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="mmatch-demo", help="output folder")
    p.add_argument("--n", type=positive_int, default=40, help="scene pairs to simulate")
    p.add_argument("--seed", type=int, default=0, help="random seed of the first scene")
    p.add_argument("--jobs", type=positive_int, default=2, help="worker processes")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mmatch.edge.commands.progress import Progress
    from mmatch.bev_plot import draw_bev
    from mmatch.evaluate import EvalConfig, evaluate_dir, format_table
    from mmatch.scene_io import load_scene
    from mmatch.sim.generate import generate
    from mmatch.sim.realism import realism_figures
    from mmatch.errors import ConfigError

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a folder")
    scenes_dir = out / "scenes"
    scenes = generate(scenes_dir, args.n, args.seed, "mixed", args.jobs, Progress("sim"))
    fig = realism_figures(scenes)
    print(f"simulated {len(scenes)} mixed scene pairs into {scenes_dir}")
    print("realism: " + ", ".join(f"{k} {v:.2f}" for k, v in fig.items() if k != "scenes"))
    cfg = EvalConfig()
    rep, results = evaluate_dir(scenes_dir, cfg, args.jobs, Progress("eval"))
    print(format_table(rep))
    (out / "eval.json").write_text(json.dumps(rep, indent=2))
    (out / "config.json").write_text(json.dumps({"n": args.n, "seed": args.seed, "mode": "mixed",
                                                 "eval": rep["config"]}, indent=2))
    done = [r for r in results if r.get("rte_m") is not None]
    if done and importlib.util.find_spec("matplotlib") is None:  # a plain `pip install mmatch`
        print("bird's-eye picture skipped: it needs matplotlib, pip install 'mmatch[plots]'")
    elif done:
        pick = sorted(done, key=lambda r: r["rte_m"])[len(done) // 2]
        scene = load_scene(pick["file"])
        picture = draw_bev(scene, np.asarray(pick["T_ego_cav"]), np.asarray(pick["box_pairs"], int),
                           out / "bev", method="MMatch")[0]
        print(f"bird's-eye picture of {scene.name} (median error scene): {picture}")
    print(f"wrote {out / 'eval.json'}")
    return 0
