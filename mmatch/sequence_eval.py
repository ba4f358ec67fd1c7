"""Evaluate sequences (DESIGN.md "Sequences"): tracked fusion over time beside the per-frame mode.

The files of a folder are grouped by `meta.sequence` and ordered by `meta.frame`. Every frame
pair goes through the CAV-side processing and the wire codec once; then two Fusers see it:
one with tracking (one per sequence, frames in order, configured as the vehicle service
configures its own) and one without (each frame on its own, as `mmatch eval` runs independent
scenes). Both get the per-frame figures of the eval JSON over all frames, and figures over
time: the time to the first estimate, the recovery time after a gross error, the share of
frames with a gross error emitted (see docs/formats.md "`mmatch eval --sequences`").
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from mmatch.errors import MMatchError, SceneFormatError
from mmatch.evaluate import EvalConfig, evaluate_with, prepare_scene, report, with_doppler_sign
from mmatch.metrics import is_gross
from mmatch.ego.track.objects import object_rows, track_record
from mmatch.object_eval import objects_report

log = logging.getLogger(__name__)

MODES = ("tracked", "per_frame")


@dataclass(frozen=True)
class SequenceEvalConfig:
    """eval: matcher, aligner, CAV side and confidence threshold as for `mmatch eval`;
    track_max_age_s: the tracking fuser's track age limit (the service's `ego.track_max_age_s`)."""

    eval: EvalConfig = field(default_factory=EvalConfig)
    track_max_age_s: float = 0.5


def tracking_fuser(cfg: SequenceEvalConfig):
    """A Fuser with tracking, as the vehicle service builds it (edge/pipeline.py) but with the
    evaluation's matcher, aligner and threshold."""
    from mmatch.ego.confidence import ConfidenceConfig
    from mmatch.ego.track import TrackConfig
    from mmatch.fusion import FusionConfig, Fuser
    e = cfg.eval
    return Fuser(FusionConfig(matcher=e.matcher, aligner=e.aligner, track=TrackConfig(max_age_s=cfg.track_max_age_s),
                              confidence=ConfidenceConfig(threshold=e.confidence_threshold)))


def per_frame_fuser(cfg: SequenceEvalConfig):
    """A Fuser without tracking (what `mmatch eval` uses on independent scenes)."""
    from mmatch.ego.confidence import ConfidenceConfig
    from mmatch.fusion import FusionConfig, Fuser
    e = cfg.eval
    return Fuser(FusionConfig(matcher=e.matcher, aligner=e.aligner,
                              confidence=ConfidenceConfig(threshold=e.confidence_threshold)))


def group_sequences(files: list[str]) -> tuple[dict[str, list[tuple[int, str]]], list[dict]]:
    """{sequence id: [(frame, file), ...] in frame order} and the files that could not be placed
    ({"file", "rejected"}): unreadable, or without meta.sequence / meta.frame."""
    groups: dict[str, list[tuple[int, str]]] = {}
    rejected = []
    for f in files:
        try:
            with np.load(f, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
            if not isinstance(meta, dict):
                raise ValueError("not a JSON object")
        except Exception as exc:                          # noqa: BLE001 - any unreadable file is rejected
            rejected.append({"file": f, "rejected": f"{f}: meta: unreadable ({exc})"})
            continue
        seq, frame = meta.get("sequence"), meta.get("frame")
        if not isinstance(seq, str) or not isinstance(frame, int) or isinstance(frame, bool) or frame < 0:
            rejected.append({"file": f, "rejected": f"{f}: meta has no \"sequence\" (str) and \"frame\" (int >= 0)"})
            continue
        groups.setdefault(seq, []).append((frame, f))
    for seq, items in groups.items():
        items.sort()
        frames = [k for k, _ in items]
        if len(set(frames)) != len(frames):
            dup = sorted({k for k in frames if frames.count(k) > 1})
            raise SceneFormatError(items[0][1], "meta", f"sequence {seq!r} has frame(s) {dup} twice")
    return groups, rejected


def evaluate_sequence(files: list[str], cfg: SequenceEvalConfig = SequenceEvalConfig(),
                      on_frame: Callable | None = None) -> dict[str, list[dict]]:
    """One sequence's files in frame order through a tracking and a per-frame Fuser.

    Returns {"tracked": [per-frame result], "per_frame": [...]} (the `mmatch eval` per-scene
    fields plus "sequence", "frame" and "stamp", the Ego's capture time in s; the tracked rows
    also "objects", the frame's object-track figures of mmatch/object_eval.py, and
    "fused_objects" and "tracks" as the vehicle service publishes them). on_frame(scene,
    mode, FusionResult) is called after each fusion (for tests).
    """
    from mmatch.cav.process import ViewProcessor
    from mmatch.object_eval import ObjectScore
    from mmatch.scene_io import load_scene
    fusers = {"tracked": tracking_fuser(cfg), "per_frame": per_frame_fuser(cfg)}
    # each camera calibrates its depths over the frames so far, as the vehicle service does
    processors = (ViewProcessor(), ViewProcessor()) if cfg.eval.depth_scale is None else None
    score = ObjectScore()
    out: dict[str, list[dict]] = {m: [] for m in MODES}
    for path in files:
        try:
            scene = load_scene(path)
        except SceneFormatError as exc:
            for mode in MODES:
                out[mode].append({"file": path, "rejected": str(exc)})
            continue
        try:
            prepared = prepare_scene(scene, cfg.eval, processors)
        except MMatchError as exc:
            prepared, error = None, str(exc)
        for mode in MODES:
            if prepared is None:
                res = {"scene": scene.name, "status": "no-estimate", "reason": error, "tp": 0, "predicted": 0,
                       "gt_pairs": len(scene.gt_pairs), "payload_bytes": 0, "stages_ms": {}, "rre_deg": None,
                       "rte_m": None, "success": False}
            else:
                res, result = evaluate_with(scene, cfg.eval, fusers[mode], prepared)
                if mode == "tracked":           # the object tracks, as the vehicle service keeps them
                    own, received = prepared[0], prepared[1]
                    objects = fusers[mode].track_objects(own, [(received, result)])
                    res["objects"] = score.add(scene, own, received, result, objects)
                    # what the service publishes (edge/node.py): objects with track ids, tracks
                    res["fused_objects"] = np.round(object_rows(result.objects, objects, received.sender), 6).tolist()
                    res["tracks"] = [track_record(t, float(own.stamp)) for t in objects.tracks]
                if on_frame is not None:
                    on_frame(scene, mode, result)
                fusers[mode].run_deferred()   # after the frame, as the vehicle service does
            res.update(file=path, sequence=scene.meta["sequence"], frame=int(scene.meta["frame"]),
                       stamp=float(scene.ego.stamp))
            out[mode].append(res)
    return out


def _run_one(args: tuple[list[str], SequenceEvalConfig]) -> dict[str, list[dict]]:
    return evaluate_sequence(*args)


def evaluate_sequences_dir(folder: str | Path, cfg: SequenceEvalConfig = SequenceEvalConfig(), jobs: int = 1,
                           progress: Callable[[int, int], None] | None = None) -> tuple[dict, dict[str, list[dict]]]:
    """Every sequence of `folder` (one worker per sequence when jobs > 1); returns (report, per-frame
    results by mode). Sequences run in the order of their ids."""
    files = sorted(str(p) for p in Path(folder).glob("*.npz"))
    groups, rejected = group_sequences(files)
    cfg = replace(cfg, eval=with_doppler_sign(cfg.eval, files, jobs))
    tasks = [([f for _, f in groups[s]], cfg) for s in sorted(groups)]
    results: dict[str, list[dict]] = {m: [] for m in MODES}

    def add(k: int, one: dict[str, list[dict]]) -> None:
        for m in MODES:
            results[m].extend(one[m])
        if progress:
            progress(k + 1, len(tasks))

    if jobs <= 1:
        for k, t in enumerate(tasks):
            add(k, _run_one(t))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for k, one in enumerate(pool.map(_run_one, tasks)):
                add(k, one)
    for r in rejected:
        log.warning("rejected %s", r["rejected"])
        for m in MODES:
            results[m].append(r)
    return sequence_report(results, cfg), results


def over_time(rows: list[dict]) -> dict:
    """Figures over time of one mode's per-frame results (all sequences): time to the first
    estimate (s from a sequence's first frame), recovery time after a gross error (s from the
    first frame of a run of emitted gross errors to the next emitted success), and the share of
    frames with a gross error emitted."""
    rows = [r for r in rows if "rejected" not in r]
    by_seq: dict[str, list[dict]] = {}
    for r in rows:
        by_seq.setdefault(r["sequence"], []).append(r)
    first, never, recover, unrecovered, gross_frames = [], 0, [], 0, 0
    for seq_rows in by_seq.values():
        seq_rows = sorted(seq_rows, key=lambda r: r["frame"])
        t0 = seq_rows[0]["stamp"]
        emitted = [r for r in seq_rows if r["status"] == "fused" and r["rte_m"] is not None]
        if emitted:
            first.append(emitted[0]["stamp"] - t0)
        else:
            never += 1
        start = None
        for r in seq_rows:
            if r["status"] != "fused" or r["rte_m"] is None:
                continue
            if is_gross(r["rre_deg"], r["rte_m"]):
                gross_frames += 1
                if start is None:
                    start = r["stamp"]
            elif r["success"] and start is not None:
                recover.append(r["stamp"] - start)
                start = None
        unrecovered += start is not None
    n = len(rows)
    return {"sequences": len(by_seq), "frames": n,
            "time_to_first_estimate_s": _stats(first), "never_estimated": never,
            "recovery_s": _stats(recover), "gross_runs": len(recover) + unrecovered, "unrecovered": unrecovered,
            "gross_frame_share": gross_frames / n if n else 0.0}


def _stats(x: list[float]) -> dict:
    if not x:
        return {"n": 0, "median": None, "p90": None, "max": None}
    a = np.asarray(x, float)
    return {"n": len(a), "median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max())}


def _gain(tracked: dict | None, per_frame: dict | None) -> float | None:
    """1 - tracked / per-frame (the share by which tracking lowers a figure), None when undefined."""
    if tracked is None or per_frame is None or not per_frame:
        return None
    return float(1.0 - tracked / per_frame)


def sequence_report(results: dict[str, list[dict]], cfg: SequenceEvalConfig) -> dict:
    """The `mmatch eval --sequences` JSON (docs/formats.md): per mode the eval report and the
    figures over time; the gains of tracking on the median errors."""
    modes = {}
    for m in MODES:
        rep = report(results[m], cfg.eval)
        rep.pop("config", None)
        rep["over_time"] = over_time(results[m])
        modes[m] = rep
    t, p = modes["tracked"], modes["per_frame"]
    t["objects"] = objects_report([r["objects"] for r in results["tracked"] if "objects" in r])
    return {"sequences": t["over_time"]["sequences"], "frames": t["scenes"], "rejected": t["rejected"],
            "tracked": t, "per_frame": p,
            "gain": {"rte_median": _gain(t["rte_m"]["median"], p["rte_m"]["median"]),
                     "rre_median": _gain(t["rre_deg"]["median"], p["rre_deg"]["median"])},
            "config": {"eval": asdict(cfg.eval), "track_max_age_s": cfg.track_max_age_s}}


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def format_sequence_table(rep: dict) -> str:
    """Tracked and per-frame figures side by side."""
    t, p = rep["tracked"], rep["per_frame"]
    rows = [
        ("RRE median (deg)", t["rre_deg"]["median"], p["rre_deg"]["median"], ".3f"),
        ("RRE p90 (deg)", t["rre_deg"]["p90"], p["rre_deg"]["p90"], ".3f"),
        ("RTE median (m)", t["rte_m"]["median"], p["rte_m"]["median"], ".3f"),
        ("RTE p90 (m)", t["rte_m"]["p90"], p["rte_m"]["p90"], ".3f"),
        ("success rate", t["success_rate"], p["success_rate"], ".3f"),
        ("coverage", t["coverage"], p["coverage"], ".3f"),
        ("gross among emitted", t["gross_rate"], p["gross_rate"], ".4f"),
        ("frames with gross emitted", t["over_time"]["gross_frame_share"], p["over_time"]["gross_frame_share"], ".4f"),
        ("95 % ellipse holds truth", t["calibration"], p["calibration"], ".3f"),
        ("first estimate median (s)", t["over_time"]["time_to_first_estimate_s"]["median"],
         p["over_time"]["time_to_first_estimate_s"]["median"], ".2f"),
        ("first estimate max (s)", t["over_time"]["time_to_first_estimate_s"]["max"],
         p["over_time"]["time_to_first_estimate_s"]["max"], ".2f"),
        ("never estimated (seq)", t["over_time"]["never_estimated"], p["over_time"]["never_estimated"], "d"),
        ("gross runs", t["over_time"]["gross_runs"], p["over_time"]["gross_runs"], "d"),
        ("recovery max (s)", t["over_time"]["recovery_s"]["max"], p["over_time"]["recovery_s"]["max"], ".2f"),
        ("unrecovered runs", t["over_time"]["unrecovered"], p["over_time"]["unrecovered"], "d"),
        ("latency median (ms)", t["latency_ms"]["total"]["median"], p["latency_ms"]["total"]["median"], ".1f"),
    ]
    o = t.get("objects") or {}
    lines = [f"{rep['sequences']} sequences, {rep['frames']} frames, rejected {rep['rejected']}",
             f"{'':<28}{'tracked':>10}{'per-frame':>11}"]
    lines += [f"{name:<28}{_fmt(a, f):>10}{_fmt(b, f):>11}" for name, a, b, f in rows]
    if o.get("frames"):
        v, w = o["velocity_error_mps"], o["two_view_velocity_error_mps"]
        lines.append(f"object tracks: {o['id_switches']} id switches ({_fmt(o['id_switches_per_100_frames'], '.2f')} "
                     f"per 100 frames), {_fmt(o['matched_share'], '.3f')} of the detected vehicles matched, "
                     f"{_fmt(o['false_tracks_per_frame'], '.2f')} unmatched tracks per frame; co-visible velocity "
                     f"error median {_fmt(v['median'], '.2f')} m/s, p90 {_fmt(v['p90'], '.2f')} (one-frame two-view "
                     f"solve: median {_fmt(w['median'], '.2f')})")
    g = rep["gain"]
    lines.append(f"tracking lowers the median RTE by {_fmt(g['rte_median'], '.0%')} and the median RRE by "
                 f"{_fmt(g['rre_median'], '.0%')}")
    return "\n".join(lines)
