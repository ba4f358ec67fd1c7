"""Run every method on the same scene files through `mmatch.evaluate`, and write the report folder.

Each (file, method) is one `evaluate_file` call with the method's EvalConfig, and each
method's results are aggregated by `evaluate.report`, so every figure is the one
`mmatch eval --matcher M --aligner A` gives on the same folder (the descriptor scale is
measured once on the folder, as `evaluate_dir` does). The tasks run interleaved, file by
file, so load on a shared machine falls on every method alike; timings are still a busy
machine's.
"""

from __future__ import annotations

import json
import logging
import platform
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, is_dataclass, replace
from pathlib import Path

from mmatch.evaluate import EvalConfig, evaluate_file, report, with_folder_calibration
from mmatch.report.facts import scene_facts
from mmatch.report.methods import Method, unavailable

log = logging.getLogger(__name__)
FORMAT = "mmatch-report/1"


@dataclass
class MethodRun:
    """One method's evaluation: the DESIGN.md eval report and the per-scene results (file order)."""

    method: Method
    config: EvalConfig
    eval: dict
    results: list[dict]


@dataclass
class ReportRun:
    folder: str
    files: list[str]
    cav: str
    descriptor_scale: float
    runs: list[MethodRun]
    skipped: list[tuple[Method, str]] = field(default_factory=list)
    facts: dict[str, dict | None] = field(default_factory=dict)
    confidence_threshold: float | None = None


def _task(args: tuple[int, str, EvalConfig]) -> tuple[int, dict]:
    k, path, cfg = args
    return k, evaluate_file(path, cfg)


def evaluate_methods(folder: str | Path, methods: list[Method], base: EvalConfig = EvalConfig(), jobs: int = 1,
                     progress: Callable[[int, int], None] | None = None) -> ReportRun:
    """Evaluate `methods` on every *.npz of `folder`; methods whose extra is missing are skipped.

    base: the settings every method shares (cav, descriptor scale, confidence threshold), as
    `mmatch eval` takes them; its matcher and aligner are replaced by each method's. A
    descriptor or depth scale of None is measured once on the folder, as `evaluate_dir` does.
    """
    files = sorted(str(p) for p in Path(folder).glob("*.npz"))
    base = with_folder_calibration(base, files, jobs)
    scale = base.descriptor_scale
    ready, skipped = [], []
    for m in methods:
        why = unavailable(m)
        if why:
            log.warning("skipping %s: %s", m.key, why)
            skipped.append((m, why))
        else:
            ready.append(m)
    cfgs = [replace(base, matcher=m.matcher, aligner=m.aligner, descriptor_scale=scale) for m in ready]
    tasks = [(k, f, cfg) for f in files for k, cfg in enumerate(cfgs)]
    per_method: list[list[dict]] = [[] for _ in ready]
    if jobs <= 1:
        stream = map(_task, tasks)
        pool = None
    else:
        pool = ProcessPoolExecutor(max_workers=jobs)
        stream = pool.map(_task, tasks, chunksize=max(1, min(8, len(ready))))
    try:
        for n, (k, res) in enumerate(stream):
            per_method[k].append(res)
            if progress:
                progress(n + 1, len(tasks))
    finally:
        if pool is not None:
            pool.shutdown()
    runs = [MethodRun(m, cfg, report(res, cfg), res) for m, cfg, res in zip(ready, cfgs, per_method)]
    facts = {f: scene_facts(f) for f in files}
    return ReportRun(str(folder), files, base.cav, scale, runs, skipped, facts, base.confidence_threshold)


def _component_config(kind: str, name: str) -> dict | None:
    """The dataclass settings of a matcher or aligner instance (its effective config), if it has one."""
    from mmatch.ego.registry import get_aligner, get_matcher
    inst = (get_matcher if kind == "matcher" else get_aligner)(name)
    for attr in ("cfg", "config"):
        value = getattr(inst, attr, None)
        if is_dataclass(value):
            return asdict(value)
    return None


def effective_config(run: ReportRun, jobs: int, plots: bool, options: dict | None = None) -> dict:
    """Everything that decides the report's numbers: methods and their settings, data, versions."""
    import numpy
    versions = {"python": platform.python_version(), "numpy": numpy.__version__}
    for mod in ("scipy", "matplotlib", "open3d", "small_gicp"):
        m = sys.modules.get(mod)
        if m is not None:
            versions[mod] = getattr(m, "__version__", "?")
    return {
        "format": FORMAT, "folder": run.folder, "files": len(run.files), "cav": run.cav,
        "descriptor_scale": run.descriptor_scale, "jobs": jobs, "plots": plots, "options": options,
        "methods": [{"key": r.method.key, "label": r.method.label, "group": r.method.group,
                     "eval": asdict(r.config),
                     "matcher_config": _component_config("matcher", r.method.matcher),
                     "aligner_config": _component_config("aligner", r.method.aligner)} for r in run.runs],
        "skipped": [{"key": m.key, "reason": why} for m, why in run.skipped],
        "versions": versions,
    }


def write_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=1, allow_nan=True, default=_jsonable))


def _jsonable(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def build(run: ReportRun) -> dict:
    """The report JSON: every method's eval report with the derived figures and breakdowns."""
    from collections import Counter

    from mmatch.report.methods import HEADLINE, REFERENCE
    from mmatch.report.tables import BREAKDOWNS, breakdown, derived

    ref = next((r for r in run.runs if r.method.key == REFERENCE), run.runs[0] if run.runs else None)
    ref_ms = ref.eval["latency_ms"]["total"]["median"] if ref else None
    known = [f for f in run.facts.values() if f]
    methods = []
    for r in run.runs:
        methods.append({
            "key": r.method.key, "label": r.method.label, "group": r.method.group,
            "matcher": r.method.matcher, "aligner": r.method.aligner, "eval": r.eval,
            "derived": derived(r.eval, r.results, ref_ms),
            "breakdowns": {key: breakdown(r.results, run.facts, key) for key, _ in BREAKDOWNS}})
    return {
        "format": FORMAT, "folder": run.folder, "files": len(run.files),
        "rejected": ref.eval["rejected"] if ref else 0, "cav": run.cav,
        "descriptor_scale": run.descriptor_scale, "confidence_threshold": run.confidence_threshold,
        "reference": ref.method.key if ref else None,
        "physics": ", ".join(f"{k} {v}" for k, v in sorted(Counter(f["physics"] for f in known).items())),
        "roads": ", ".join(f"{k} {v}" for k, v in sorted(Counter(f["road"] for f in known).items())),
        "headline": [k for k in HEADLINE if any(m["key"] == k for m in methods)],
        "methods": methods,
        "skipped": [{"key": m.key, "label": m.label, "matcher": m.matcher, "aligner": m.aligner,
                     "reason": why} for m, why in run.skipped],
    }


def write_report(out: str | Path, run: ReportRun, jobs: int = 1, plots: bool = True,
                 options: dict | None = None, bev_method: str = "mmatch") -> dict:
    """Write report.json, summary.md, config.json, scenes/KEY.scenes.json and (plots) the figures.

    Returns the report JSON. Figures need matplotlib (the `plots` extra): ConfigError without.
    """
    from mmatch.report.tables import markdown

    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    rep = build(run)
    for r in run.runs:
        write_json(out / "scenes" / f"{r.method.key}.scenes.json", r.results)
    figures: list[str] = []
    if plots and run.runs:
        from mmatch.report.plots import draw_all
        figures = draw_all(out, rep, run, bev_method)
    rep["figures"] = figures
    write_json(out / "report.json", rep)
    write_json(out / "config.json", effective_config(run, jobs, plots, options))
    (out / "summary.md").write_text(markdown(rep, figures))
    return rep
