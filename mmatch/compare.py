"""Two evaluation runs of the same scenes compared scene by scene (as evo_res compares results).

Pooled figures hide how a change moved: a success rate up by one scene may be ten scenes gained
and nine lost. `compare` pairs two runs' per-scene results (`mmatch eval --json FILE` writes
them to FILE.scenes.json, and with `--sequences` the tracked frames to FILE.frames.json) by
scene file, classes each scene's outcome as right, off (emitted, neither right nor gross),
gross (emitted with RRE > 10 deg or RTE > 5 m, metrics.py) or refused ("no estimate"), and
counts the moves between the classes. For the scenes right and the gross estimates emitted it
gives the scenes that changed each way and the exact two-sided sign test (McNemar's exact
test): the probability, were neither run better, of a split at least as lopsided.
"""

from __future__ import annotations

import json
from math import comb
from pathlib import Path

from mmatch.errors import ConfigError
from mmatch.metrics import is_gross

OUTCOMES: tuple[str, ...] = ("right", "off", "gross", "refused")


def outcome(row: dict) -> str:
    """The class of one scene's result (an object of FILE.scenes.json): see the module doc."""
    if row.get("status") != "fused":
        return "refused"
    if row.get("success"):
        return "right"
    rre, rte = row.get("rre_deg"), row.get("rte_m")
    return "gross" if rre is not None and rte is not None and is_gross(rre, rte) else "off"


def sign_test(gained: int, lost: int) -> float:
    """Exact two-sided sign-test probability of a split of gained + lost changed scenes at least
    as uneven as this one when each change is a fair coin (1.0 when nothing changed)."""
    n = gained + lost
    if n == 0:
        return 1.0
    tail = sum(comb(n, i) for i in range(min(gained, lost) + 1)) / 2 ** n
    return min(1.0, 2.0 * tail)


def load_rows(reports: str | Path | list) -> dict[str, dict]:
    """The per-scene results beside one eval report FILE.json or several (pooled), keyed by
    scene file (its folder's name and its own: two runs of one folder pair up wherever each ran
    from): FILE.scenes.json, else the tracked frames of FILE.frames.json."""
    if isinstance(reports, (list, tuple)):
        out: dict[str, dict] = {}
        for r in reports:
            out.update(load_rows(r))
        return out
    path = Path(reports)
    stem = path.with_suffix("") if path.suffix == ".json" else path
    scenes, frames = Path(f"{stem}.scenes.json"), Path(f"{stem}.frames.json")
    try:
        if scenes.is_file():
            rows = json.loads(scenes.read_text(encoding="utf-8"))
        elif frames.is_file():
            rows = json.loads(frames.read_text(encoding="utf-8"))["tracked"]
        else:
            raise ConfigError(f"{path}: neither {scenes.name} nor {frames.name} beside it "
                              "(written by `mmatch eval --json`)")
        return {_key(r): r for r in rows}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: per-scene results unreadable ({exc})") from exc


def _key(row: dict) -> str:
    f = row.get("file")
    return "/".join(Path(f).parts[-2:]) if f else str(row["scene"])


def _summary(rows: list[dict], kinds: list[str]) -> dict:
    """One run's figures over its rows, whose outcomes (`outcome`) are `kinds`."""
    n = len(rows)
    emitted = n - kinds.count("refused")
    tp = sum(int(r.get("tp", 0)) for r in rows)
    pred = sum(int(r.get("predicted", 0)) for r in rows)
    gt = sum(int(r.get("gt_pairs", 0)) for r in rows)
    p, rc = tp / pred if pred else 0.0, tp / gt if gt else 0.0
    return {"scenes": n, **{k: kinds.count(k) for k in OUTCOMES},
            "success_rate": kinds.count("right") / n if n else 0.0,
            "coverage": emitted / n if n else 0.0,
            "gross_rate": kinds.count("gross") / emitted if emitted else 0.0,
            "pair_f1": 2 * p * rc / (p + rc) if p + rc else 0.0}


def _paired(a: list[str], b: list[str], kind: str) -> dict:
    gained = sum(x != kind and y == kind for x, y in zip(a, b))
    lost = sum(x == kind and y != kind for x, y in zip(a, b))
    return {"gained": gained, "lost": lost, "p_value": sign_test(gained, lost)}


def compare(a: dict[str, dict], b: dict[str, dict]) -> dict:
    """Two runs' per-scene results (`load_rows`) on their common scenes: each run's figures
    ("a", "b"), the moves between outcome classes ("moves": {"right->refused": n, ...}), and
    the paired changes of the scenes right and of the gross estimates emitted ("right",
    "gross": gained, lost, p_value). "only_a" / "only_b": scenes in one run only."""
    common = sorted(set(a) & set(b))
    ka, kb = [outcome(a[s]) for s in common], [outcome(b[s]) for s in common]
    moves: dict[str, int] = {}
    for x, y in zip(ka, kb):
        if x != y:
            moves[f"{x}->{y}"] = moves.get(f"{x}->{y}", 0) + 1
    return {"scenes": len(common), "only_a": len(set(a) - set(b)), "only_b": len(set(b) - set(a)),
            "a": _summary([a[s] for s in common], ka), "b": _summary([b[s] for s in common], kb),
            "moves": dict(sorted(moves.items(), key=lambda kv: (-kv[1], kv[0]))),
            "right": _paired(ka, kb, "right"), "gross": _paired(ka, kb, "gross")}


def format_comparison(c: dict, name_a: str = "A", name_b: str = "B") -> str:
    """The comparison as a plain-text table."""
    a, b = c["a"], c["b"]
    lines = [f"{c['scenes']} scenes in both runs" + (f" ({c['only_a']} only in {name_a}, {c['only_b']} only in "
                                                    f"{name_b}: left out)" if c["only_a"] or c["only_b"] else ""),
             f"{'':22s}{name_a:>12s}{name_b:>12s}"]
    for key, label in (("success_rate", "success rate"), ("coverage", "coverage"),
                       ("gross_rate", "gross among emitted"), ("pair_f1", "pair F1")):
        lines.append(f"{label:22s}{a[key]:12.4f}{b[key]:12.4f}")
    for key in OUTCOMES:
        lines.append(f"{key + ' (scenes)':22s}{a[key]:12d}{b[key]:12d}")
    moves = ", ".join(f"{k} {v}" for k, v in c["moves"].items()) or "none"
    lines.append(f"scenes that changed: {moves}")
    for key, label in (("right", "right"), ("gross", "gross emitted")):
        d = c[key]
        lines.append(f"{label}: {d['gained']} gained, {d['lost']} lost (sign test p = {d['p_value']:.3f})")
    return "\n".join(lines)
