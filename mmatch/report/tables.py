"""The report's figures beyond the eval JSON, its breakdowns by scene, and its markdown.

Every figure is computed from a method's eval report and per-scene results as `mmatch eval`
writes them (FILE.json and FILE.scenes.json), so anyone can recompute it from those files:
success at stricter thresholds (RRE < a deg and RTE < b m, over all non-rejected scenes, a
scene without an estimate failing), pair F1, the Ego-side time (matching + alignment,
median ms), the whole per-frame time as a ratio to MMatch's.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

THRESHOLDS: tuple[tuple[str, float, float], ...] = (("5deg_2m", 5.0, 2.0), ("2deg_1m", 2.0, 1.0),
                                                    ("1deg_0.5m", 1.0, 0.5))
BREAKDOWNS: tuple[tuple[str, str], ...] = (("co_visible", "co-visible vehicles"),
                                           ("vehicles_per_view", "vehicles per view"),
                                           ("road", "road type"), ("relation", "driving direction"))
PIPELINE_ORDER = ("egomotion", "separation", "clustering", "background", "encode", "decode", "matching",
                  "alignment")
MIN_BIN = 5          # numeric breakdowns merge their tails until each end bin has this many scenes


def scored(results: list[dict]) -> list[dict]:
    """The per-scene results that count (not rejected files)."""
    return [r for r in results if "rejected" not in r]


def success_at(results: list[dict], rre_max: float, rte_max: float) -> float:
    ok = scored(results)
    if not ok:
        return 0.0
    hit = [r["rte_m"] is not None and r["rre_deg"] < rre_max and r["rte_m"] < rte_max for r in ok]
    return float(np.mean(hit))


def f1(precision: float, recall: float) -> float:
    return 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0


def ego_ms(results: list[dict]) -> float:
    """Median ms of the Ego side (matching + alignment) per scene; NaN without timings."""
    t = [r["stages_ms"].get("matching", 0.0) + r["stages_ms"].get("alignment", 0.0)
         for r in scored(results) if r["stages_ms"]]
    return float(np.median(t)) if t else float("nan")


def derived(rep: dict, results: list[dict], reference_ms: float | None) -> dict:
    """Table figures of one method: success at each threshold, F1, times, ratio to the reference."""
    ms = rep["latency_ms"]["total"]["median"]
    return {
        "success": {name: success_at(results, a, b) for name, a, b in THRESHOLDS},
        "pair_f1": f1(rep["pair_precision"], rep["pair_recall"]),
        "ms_per_frame": ms,
        "ego_ms": ego_ms(results),
        "time_ratio": ms / reference_ms if reference_ms else float("nan"),
    }


def _bins(values: list, numeric: bool) -> dict:
    """value -> bin label; numeric tails merged into '<=v' / '>=v' bins of at least MIN_BIN scenes."""
    counts = Counter(values)
    if not numeric:
        return {v: str(v) for v in counts}
    keys = sorted(counts)
    lo, hi = 0, len(keys) - 1
    while hi > lo and sum(counts[k] for k in keys[hi:]) < MIN_BIN:
        hi -= 1
    while lo < hi and sum(counts[k] for k in keys[:lo + 1]) < MIN_BIN:
        lo += 1
    out = {}
    for i, k in enumerate(keys):
        if i >= hi and hi < len(keys) - 1:
            out[k] = f">={keys[hi]}"
        elif i <= lo and lo > 0:
            out[k] = f"<={keys[lo]}"
        else:
            out[k] = str(k)
    return out


def breakdown(results: list[dict], facts: dict[str, dict | None], key: str) -> list[dict]:
    """Per bin of a scene fact: scenes, success (5 deg / 2 m), RTE and RRE medians of the estimates."""
    rows = [(facts.get(r["file"]) or {}, r) for r in scored(results)]
    rows = [(f[key], r) for f, r in rows if key in f]
    if not rows:
        return []
    numeric = all(isinstance(v, int) for v, _ in rows)
    label = _bins([v for v, _ in rows], numeric)
    order = sorted({v for v, _ in rows})
    out, seen = [], set()
    for v in order:
        b = label[v]
        if b in seen:
            continue
        seen.add(b)
        members = [r for w, r in rows if label[w] == b]
        est = [r for r in members if r["rte_m"] is not None]
        out.append({"bin": b, "scenes": len(members),
                    "success_rate": float(np.mean([r["success"] for r in members])),
                    "rte_median_m": float(np.median([r["rte_m"] for r in est])) if est else float("nan"),
                    "rre_median_deg": float(np.median([r["rre_deg"] for r in est])) if est else float("nan")})
    return out


def _num(x, fmt: str = ".2f") -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def method_table(methods: list[dict]) -> list[str]:
    """The headline table, one row per method (markdown lines)."""
    lines = ["| method | matcher + aligner | success 5°/2 m | 2°/1 m | 1°/0.5 m | RRE med / mean / p90 (deg) "
             "| RTE med / mean / p90 (m) | pair P / R / F1 | ms / frame | × MMatch | payload (B) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for m in methods:
        e, d = m["eval"], m["derived"]
        s = d["success"]
        rre, rte = e["rre_deg"], e["rte_m"]
        pairs = "—" if m["matcher"] == "none" else \
            f"{e['pair_precision']:.3f} / {e['pair_recall']:.3f} / {d['pair_f1']:.3f}"
        lines.append(
            f"| {m['label']} | {m['matcher']} + {m['aligner']} | {s['5deg_2m']:.3f} | {s['2deg_1m']:.3f} "
            f"| {s['1deg_0.5m']:.3f} | {_num(rre['median'])} / {_num(rre['mean'])} / {_num(rre['p90'])} "
            f"| {_num(rte['median'])} / {_num(rte['mean'])} / {_num(rte['p90'])} | {pairs} "
            f"| {_num(d['ms_per_frame'], '.1f')} | {_num(d['time_ratio'])} "
            f"| {_num(e['payload_bytes']['median'], '.0f')} |")
    return lines


def breakdown_table(methods: list[dict], key: str, title: str) -> list[str]:
    """Success (RTE median) per bin of `key`, one row per method."""
    bins: list[str] = []
    for m in methods:
        for row in m["breakdowns"].get(key, []):
            if row["bin"] not in bins:
                bins.append(row["bin"])
    if not bins:
        return []
    counts = {row["bin"]: row["scenes"] for row in methods[0]["breakdowns"].get(key, [])}
    head = " | ".join(f"{b} (n={counts.get(b, 0)})" for b in bins)
    lines = [f"| {title}: success (RTE median m) | {head} |", "| --- |" + " --- |" * len(bins)]
    for m in methods:
        cells = {row["bin"]: f"{row['success_rate']:.2f} ({_num(row['rte_median_m'], '.1f')})"
                 for row in m["breakdowns"].get(key, [])}
        lines.append(f"| {m['label']} | " + " | ".join(cells.get(b, "") for b in bins) + " |")
    return lines


def stage_order(methods: list[dict]) -> list[str]:
    """Every stage any method timed, in pipeline order (unknown stages after)."""
    seen = [s for m in methods for s in m["eval"]["latency_ms"]["stages"]]
    return [s for s in PIPELINE_ORDER if s in seen] + sorted(set(seen) - set(PIPELINE_ORDER))


def stage_table(methods: list[dict]) -> list[str]:
    stages = stage_order(methods)
    lines = ["| method | " + " | ".join(stages) + " | total median / p90 |",
             "| --- |" + " --- |" * (len(stages) + 1)]
    for m in methods:
        st = m["eval"]["latency_ms"]["stages"]
        tot = m["eval"]["latency_ms"]["total"]
        lines.append(f"| {m['label']} | " + " | ".join(_num(st[s]["median"]) if s in st else "" for s in stages)
                     + f" | {tot['median']:.1f} / {tot['p90']:.1f} |")
    return lines


def markdown(rep: dict, figures: list[str]) -> str:
    """The report's summary.md: data, methods table, breakdowns, latency, skipped methods, figures."""
    methods = rep["methods"]
    thr = rep.get("confidence_threshold")
    gate = "the fitted model's" if thr is None else f"{thr:g}"
    out = [f"# MMatch report: {rep['folder']}", "",
           f"{rep['files']} scene files ({rep['rejected']} rejected), CAV side `{rep['cav']}`, descriptor scale "
           f"{rep['descriptor_scale']:.3f}, confidence threshold {gate}; physics: {rep['physics']}; "
           f"roads: {rep['roads']}.",
           "Success: RRE < a deg and RTE < b m over all scenes (no estimate = failure); RRE / RTE over the "
           "scenes with an estimate. Times are medians per frame pair on a shared machine (whole path: "
           "CAV-side processing, codec, matching, alignment); × MMatch is the ratio of those medians.", ""]
    out += method_table(methods) + [""]
    for m, why in ((s["label"], s["reason"]) for s in rep["skipped"]):
        out.append(f"- skipped {m}: {why}")
    if rep["skipped"]:
        out.append("")
    shown = [m for m in methods if m["key"] in rep["headline"]] or methods
    for key, title in BREAKDOWNS:
        lines = breakdown_table(shown, key, title)
        if lines:
            out += [f"## By {title}", ""] + lines + [""]
    out += ["## Latency per stage (median ms)", ""] + stage_table(methods) + [""]
    risk = [m for m in methods if finite_risk(m["eval"])]
    if risk:
        out += ["## Confidence", "", "| method | coverage | gross rate | calibration |", "| --- | --- | --- | --- |"]
        out += [f"| {m['label']} | {_num(m['eval'].get('coverage'))} | {_num(m['eval'].get('gross_rate'))} "
                f"| {_num(m['eval'].get('calibration'))} |" for m in risk] + [""]
    if figures:
        out += ["## Figures", ""] + [f"![{f}]({f})" for f in figures if f.endswith(".png")] + [""]
    return "\n".join(out)


def finite_risk(ev: dict) -> bool:
    """Does an eval report carry a risk-coverage curve with finite values (confidence exists)?"""
    rc = ev.get("risk_coverage")
    if not isinstance(rc, list) or not rc:
        return False
    try:
        return all(math.isfinite(float(p["coverage"])) and math.isfinite(float(p["gross_rate"])) for p in rc)
    except (KeyError, TypeError, ValueError):
        return False
