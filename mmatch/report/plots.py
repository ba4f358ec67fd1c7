"""The report's figures (matplotlib, `plots` extra), each written as PNG and SVG.

cdf: RRE and RTE per method (a scene without an estimate never arrives, so a curve ends
below 1 by the no-estimate share); by_co_visible / by_vehicles_per_view: success and RTE
median against the scene's co-visible vehicles (the paper's "detection missing" figure)
and vehicles per view; by_road_direction: the same per road type and driving direction;
latency: median ms per stage; payload: bytes per shared frame; risk_coverage: gross-error
rate and success against coverage when the evaluation has finite confidence figures;
bev_success / bev_failure: one scene each (bev_plot.py).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mmatch.errors import ConfigError
from mmatch.report.tables import THRESHOLDS, finite_risk, scored, stage_order

GROUP_STYLE = {"ours": "-", "yardstick": "-.", "ablation": "--", "peer": ":", "custom": "-"}
PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf", "#393b79", "#ad494a", "#637939", "#843c39")
MARKERS = "osD^v<>pPXh*d8"
DPI = 100


def pyplot():
    """matplotlib.pyplot on the Agg backend, or ConfigError with the install line."""
    try:
        import matplotlib
    except ImportError as exc:
        raise ConfigError("figures need matplotlib: pip install 'mmatch[plots]' "
                          "(or mmatch report --no-plots)") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    plt.rcParams.update({"figure.facecolor": "white", "axes.facecolor": "white", "axes.grid": True,
                         "grid.color": "#dddddd", "grid.linewidth": 0.6, "font.size": 9,
                         "axes.titlesize": 10, "legend.fontsize": 8, "svg.fonttype": "none",
                         "savefig.bbox": "tight"})
    return plt


def save_figure(fig, stem: Path, formats=("png", "svg"), dpi: int = DPI) -> list[Path]:
    """Write STEM.<format> for each format and close the figure; returns the files.

    PNGs are stored with a 256-colour palette (MAXCOVERAGE keeps every drawn colour within a
    few levels): about a third of matplotlib's size, small enough for the README.
    """
    from PIL import Image

    plt = pyplot()
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    written = []
    for ext in formats:
        f = stem.with_name(f"{stem.name}.{ext}")
        fig.savefig(f, dpi=dpi, metadata={"Software": None} if ext == "png" else None)
        if ext == "png":
            with Image.open(f) as im:
                small = im.convert("RGB").quantize(colors=256, method=Image.Quantize.MAXCOVERAGE,
                                                   dither=Image.Dither.NONE)
            small.save(f, optimize=True)
        written.append(f)
    plt.close(fig)
    return written


def save(fig, out: Path, name: str) -> list[str]:
    """Write NAME.png and NAME.svg into `out`; returns their file names."""
    return [f.name for f in save_figure(fig, Path(out) / name)]


def _style(k: int, method: dict) -> dict:
    return {"color": PALETTE[k % len(PALETTE)], "linestyle": GROUP_STYLE.get(method["group"], "-"),
            "marker": MARKERS[k % len(MARKERS)]}


def cdf_figure(out: Path, rep: dict, results: dict[str, list[dict]]) -> list[str]:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for k, m in enumerate(rep["methods"]):
        ok = scored(results[m["key"]])
        n = max(len(ok), 1)
        st = _style(k, m)
        for ax, field in zip(axes, ("rre_deg", "rte_m")):
            v = np.sort([r[field] for r in ok if r[field] is not None])
            if len(v) == 0:
                continue
            v = np.maximum(v, 1e-3)
            ax.step(np.concatenate([[1e-3], v]), np.arange(len(v) + 1) / n, where="post",
                    color=st["color"], linestyle=st["linestyle"], lw=1.4, label=m["label"])
    for ax, (label, limit) in zip(axes, (("RRE (deg)", THRESHOLDS[0][1]), ("RTE (m)", THRESHOLDS[0][2]))):
        ax.set_xscale("log")
        ax.set_xlim(0.05, 200)
        ax.set_ylim(0, 1)
        ax.axvline(limit, color="#555555", lw=0.8, ls=":")
        ax.set_xlabel(label + ", log scale")
        ax.set_ylabel("share of scenes")
    axes[0].set_title(f"RRE, success below {THRESHOLDS[0][1]:g} deg (dotted)")
    axes[1].set_title(f"RTE, success below {THRESHOLDS[0][2]:g} m (dotted)")
    axes[1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    return save(fig, out, "cdf")


def _headline(rep: dict) -> list[tuple[int, dict]]:
    return [(k, m) for k, m in enumerate(rep["methods"]) if m["key"] in rep["headline"]] \
        or list(enumerate(rep["methods"]))


def _bins_of(rep: dict, key: str) -> list[tuple[str, int]]:
    first = rep["methods"][0]["breakdowns"].get(key, [])
    return [(row["bin"], row["scenes"]) for row in first]


def line_breakdown(out: Path, rep: dict, key: str, title: str) -> list[str]:
    """Success and RTE median against a numeric scene fact, one line per headline method."""
    bins = _bins_of(rep, key)
    if not bins:
        return []
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(bins))
    for k, m in _headline(rep):
        rows = {r["bin"]: r for r in m["breakdowns"].get(key, [])}
        st = _style(k, m)
        s = [rows[name]["success_rate"] if name in rows else np.nan for name, _ in bins]
        e = [rows[name]["rte_median_m"] if name in rows else np.nan for name, _ in bins]
        a.plot(x, s, label=m["label"], ms=5, lw=1.4, **st)
        b.plot(x, e, label=m["label"], ms=5, lw=1.4, **st)
    ticks = [f"{name}\n(n={n})" for name, n in bins]
    for ax in (a, b):
        ax.set_xticks(x, ticks)
        ax.set_xlabel(title)
    a.set_ylim(0, 1.02)
    a.set_ylabel("success (5 deg / 2 m)")
    a.set_title(f"success against {title}")
    b.set_yscale("log")
    b.set_ylabel("RTE median of the estimates (m), log")
    b.set_title(f"RTE against {title}")
    b.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    return save(fig, out, f"by_{key}")


def bar_breakdowns(out: Path, rep: dict) -> list[str]:
    """Success and RTE median per road type and per driving direction (grouped bars)."""
    keys = [("road", "road type"), ("relation", "driving direction")]
    if not any(_bins_of(rep, k) for k, _ in keys):
        return []
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5))
    shown = _headline(rep)
    width = 0.8 / max(len(shown), 1)
    for col, (key, title) in enumerate(keys):
        bins = _bins_of(rep, key)
        x = np.arange(len(bins))
        for j, (k, m) in enumerate(shown):
            rows = {r["bin"]: r for r in m["breakdowns"].get(key, [])}
            colour = _style(k, m)["color"]
            s = [rows[n]["success_rate"] if n in rows else 0 for n, _ in bins]
            e = [rows[n]["rte_median_m"] if n in rows else np.nan for n, _ in bins]
            axes[0, col].bar(x - 0.4 + width * (j + 0.5), s, width, color=colour, label=m["label"])
            axes[1, col].bar(x - 0.4 + width * (j + 0.5), e, width, color=colour, label=m["label"])
        for row in (0, 1):
            axes[row, col].set_xticks(x, [f"{n}\n(n={c})" for n, c in bins])
        axes[0, col].set_ylim(0, 1.02)
        axes[0, col].set_ylabel("success (5 deg / 2 m)")
        axes[0, col].set_title(f"success per {title}")
        axes[1, col].set_yscale("log")
        axes[1, col].set_ylabel("RTE median (m), log")
        axes[1, col].set_title(f"RTE per {title}")
    axes[0, 1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    fig.tight_layout()
    return save(fig, out, "by_road_direction")


def latency_figure(out: Path, rep: dict) -> list[str]:
    plt = pyplot()
    methods = rep["methods"]
    stages = stage_order(methods)
    fig, ax = plt.subplots(figsize=(9, 0.42 * len(methods) + 1.4))
    y = np.arange(len(methods))[::-1]
    left = np.zeros(len(methods))
    colours = [plt.get_cmap("tab10")(i % 10) for i in range(len(stages))]
    for s, c in zip(stages, colours):
        v = np.array([m["eval"]["latency_ms"]["stages"].get(s, {"median": 0.0})["median"] for m in methods])
        ax.barh(y, v, left=left, color=c, label=s, height=0.7)
        left += v
    ax.set_yticks(y, [m["label"] for m in methods])
    ax.set_xlabel("median ms per frame pair, by stage (shared 2-core machine)")
    ax.set_title("latency per stage")
    ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    return save(fig, out, "latency")


def payload_figure(out: Path, rep: dict, results: list[dict]) -> list[str]:
    b = np.array([r["payload_bytes"] for r in scored(results) if r["payload_bytes"]], float)
    if len(b) == 0:
        return []
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.hist(b / 1000.0, bins=np.arange(0.0, b.max() / 1000.0 + 0.1, 0.05), color="#1f77b4")
    ax.axvline(np.median(b) / 1000.0, color="#d62728", lw=1.2, label=f"median {np.median(b):.0f} B")
    ax.axvspan(5, 9, color="#999999", alpha=0.15, label="paper: 5-9 KB")
    ax.set_xlabel("shared frame on the wire (KB)")
    ax.set_ylabel("scenes")
    ax.set_title("payload per shared frame")
    ax.legend(frameon=False)
    return save(fig, out, "payload")


def risk_coverage_figure(out: Path, rep: dict) -> list[str]:
    rows = [(k, m) for k, m in enumerate(rep["methods"]) if finite_risk(m["eval"])]
    if not rows:
        return []
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    for k, m in rows:
        rc = m["eval"]["risk_coverage"]
        cov = [float(p["coverage"]) for p in rc]
        st = _style(k, m)
        a.plot(cov, [float(p["gross_rate"]) for p in rc], label=m["label"], ms=4, **st)
        sr = [float(p.get("success_rate", math.nan)) for p in rc]
        if np.isfinite(sr).any():
            b.plot(cov, sr, label=m["label"], ms=4, **st)
    a.set_xlabel("coverage (share of scenes given an estimate, most confident first)")
    a.set_ylabel("gross-error rate (RRE > 10 deg or RTE > 5 m)")
    a.set_title("risk against coverage")
    b.set_xlabel("coverage")
    b.set_ylabel("success among the kept")
    b.set_title("success against coverage")
    b.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    return save(fig, out, "risk_coverage")


def pick_cases(results: list[dict]) -> tuple[dict | None, dict | None]:
    """A typical success (median RTE among successes) and failure (median RTE among failed estimates)."""
    ok = scored(results)
    good = sorted((r for r in ok if r["success"] and r.get("T_ego_cav")), key=lambda r: r["rte_m"])
    bad = sorted((r for r in ok if not r["success"] and r.get("T_ego_cav")), key=lambda r: r["rte_m"])
    return (good[len(good) // 2] if good else None), (bad[len(bad) // 2] if bad else None)


def bev_figures(out: Path, rep: dict, results: list[dict], label: str) -> list[str]:
    from mmatch.bev_plot import draw_bev
    from mmatch.scene_io import load_scene

    names = []
    for case, r in zip(("success", "failure"), pick_cases(results)):
        if r is None:
            continue
        scene = load_scene(r["file"])
        T = np.asarray(r["T_ego_cav"], float)
        written = draw_bev(scene, T, np.asarray(r.get("box_pairs", []), int).reshape(-1, 2),
                           out / f"bev_{case}", method=label, formats=("png", "svg"))
        names += [p.name for p in written]
    return names


def draw_all(out: Path, rep: dict, run, bev_method: str = "mmatch") -> list[str]:
    """Every figure the report has data for; returns the written file names (PNG and SVG)."""
    results = {r.method.key: r.results for r in run.runs}
    ref = bev_method if bev_method in results else rep["reference"]
    label = next(m["label"] for m in rep["methods"] if m["key"] == ref)
    names = cdf_figure(out, rep, results)
    names += line_breakdown(out, rep, "co_visible", "co-visible vehicles")
    names += line_breakdown(out, rep, "vehicles_per_view", "vehicles per view")
    names += bar_breakdowns(out, rep)
    names += latency_figure(out, rep)
    names += payload_figure(out, rep, results[rep["reference"]])
    names += risk_coverage_figure(out, rep)
    names += bev_figures(out, rep, results[ref], label)
    return names
