"""Pipeline speed benchmark for `mmatch bench`: per-stage milliseconds and payload bytes.

Runs on simulated mixed scenes held in memory: both views through the CAV-side
processing, the CAV frame through the codec, then matching and alignment.
"""

from __future__ import annotations

import numpy as np

from mmatch.evaluate import EvalConfig, evaluate_scene
from mmatch.sim.scenario import make_scene


def run(quick: bool = False) -> dict:
    """Median per-stage ms, total ms (median, p90) and payload bytes (median, max)."""
    n = 6 if quick else 60
    scenes = [make_scene(seed=21, index=i, mode="hard" if i % 2 else "easy") for i in range(n)]
    evaluate_scene(scenes[0], EvalConfig())          # warm-up: imports, first-call costs
    results = [evaluate_scene(s, EvalConfig()) for s in scenes]
    stages = sorted({k for r in results for k in r["stages_ms"]})
    out: dict = {"scenes": n}
    for s in stages:
        out[f"{s}_ms_median"] = round(float(np.median([r["stages_ms"][s] for r in results
                                                        if s in r["stages_ms"]])), 3)
    totals = [sum(r["stages_ms"].values()) for r in results]
    out["total_ms_median"] = round(float(np.median(totals)), 2)
    out["total_ms_p90"] = round(float(np.percentile(totals, 90)), 2)
    payload = [r["payload_bytes"] for r in results]
    out["payload_bytes_median"] = float(np.median(payload))
    out["payload_bytes_max"] = float(np.max(payload))
    return out
