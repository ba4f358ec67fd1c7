"""The matcher ablation: several matchers, one run, the same scenes and the same aligner.

`mmatch ablation DIR` evaluates every `*.npz` of DIR once per matcher (default: RM-net with
geometric verification, RM-net alone, consensus with RM-net's pairs (the default),
consensus, descriptor only, geometry only), with the
descriptor scale measured once on the folder, and reports pair precision / recall / F1,
RRE / RTE and latency side by side (a Markdown table for the README, and JSON).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from mmatch.evaluate import EvalConfig, evaluate_dir, with_folder_calibration

ABLATION = ("rmnet", "rmnet-only", "consensus-rmnet", "consensus", "descriptor", "geometry")
LABELS = {"rmnet": "RM-net + verification", "rmnet-only": "RM-net alone",
          "consensus-rmnet": "consensus search, RM-net pairs (default)", "consensus": "consensus (no learning)",
          "descriptor": "descriptor only", "geometry": "geometry only"}


def run_ablation(folder: str | Path, matchers: tuple[str, ...] = ABLATION, cfg: EvalConfig = EvalConfig(),
                 jobs: int = 1, progress: Callable[[str], Callable[[int, int], None] | None] | None = None) -> dict:
    """{matcher: DESIGN.md eval report} on the same files; the descriptor and depth scales are measured once."""
    files = sorted(str(p) for p in Path(folder).glob("*.npz"))
    cfg = with_folder_calibration(cfg, files, jobs)
    out = {}
    for m in matchers:
        rep, _ = evaluate_dir(folder, replace(cfg, matcher=m), jobs, progress(m) if progress else None)
        out[m] = rep
    return out


def f1(rep: dict) -> float:
    p, r = rep["pair_precision"], rep["pair_recall"]
    return 2 * p * r / (p + r) if p + r else 0.0


def markdown(reports: dict) -> str:
    """A Markdown table of the ablation (one row per matcher)."""
    lines = ["| matcher | pair P / R / F1 | success | RRE median / p90 (deg) | RTE median / p90 (m) "
             "| matching ms median | total ms median / p90 |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for m, rep in reports.items():
        st = rep["latency_ms"]["stages"].get("matching", {"median": 0.0})["median"]
        lines.append(
            f"| {LABELS.get(m, m)} (`{m}`) | {rep['pair_precision']:.3f} / {rep['pair_recall']:.3f} / "
            f"**{f1(rep):.3f}** | {rep['success_rate']:.3f} | {rep['rre_deg']['median']:.2f} / "
            f"{rep['rre_deg']['p90']:.1f} | {rep['rte_m']['median']:.2f} / {rep['rte_m']['p90']:.1f} | {st:.1f} | "
            f"{rep['latency_ms']['total']['median']:.1f} / {rep['latency_ms']['total']['p90']:.1f} |")
    return "\n".join(lines)
