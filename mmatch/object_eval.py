"""Fused object tracks against a sequence's ground truth: id switches (CLEAR MOT) and velocity errors.

Per Ego frame the ground truth objects are the vehicles a view of the frame detects (own boxes;
the CAV's too when the frame was fused), at their true centres (`meta.vehicle_position`, Ego
radar frame at the Ego's capture time, docs/formats.md "Sequences"). The published tracks are
matched to them as CLEAR MOT does (Bernardin and Stiefelhagen 2008): a pair matched in the last
frame stays matched while it is within the distance limit, the rest by the Hungarian method
on distance; the limit is `max_distance_m` or `max_distance_rel` of the range, whichever is
larger. An id switch is a vehicle matched to another track than the last time it was matched.
The velocity error is the matched track's velocity against `meta.vehicle_velocity`, for
vehicles both views detect in a fused frame (co-visible); beside it the one-frame two-view
solve of the matched pairs (ego/confidence.py `two_view_velocities`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def _ids_of(frame, box_ids: np.ndarray | None) -> np.ndarray:
    """(V,) ground-truth vehicle id of each vehicle of a SharedFrame (-1: none or unknown)."""
    if box_ids is None or frame.num_vehicles == 0:
        return np.full(frame.num_vehicles, -1)
    b = np.asarray(box_ids)
    idx = np.asarray(frame.vehicle_box_index, int)
    ok = (idx >= 0) & (idx < len(b))
    out = np.full(frame.num_vehicles, -1)
    out[ok] = b[idx[ok]]
    return out


def _stats(x: list[float]) -> dict:
    if not x:
        return {"n": 0, "median": None, "p90": None}
    a = np.asarray(x, float)
    return {"n": int(len(a)), "median": float(np.median(a)), "p90": float(np.percentile(a, 90))}


class ObjectScore:
    """The object figures of one drive's frames, frame by frame (`add`); `objects_report` sums
    the per-frame figures of any number of drives."""

    def __init__(self, max_distance_m: float = 3.0, max_distance_rel: float = 0.05) -> None:
        self.max_distance_m, self.max_distance_rel = max_distance_m, max_distance_rel
        self._last: dict[int, int] = {}

    def add(self, scene, own, other, result, objects) -> dict:
        """One Ego frame: the Scene (ground truth), the own and received SharedFrames, the
        FusionResult and the ObjectFrame of `Fuser.track_objects` (None: no tracks). Returns the
        frame's figures {"objects", "matched", "id_switches", "false_tracks", "velocity_errors",
        "two_view_errors"} (counts; errors in m/s)."""
        from mmatch.ego.confidence import two_view_velocities
        meta = scene.meta or {}
        pos, vel = meta.get("vehicle_position", {}), meta.get("vehicle_velocity", {})
        fused = result.status == "fused" and result.T_ego_cav is not None
        ge = {int(g) for g in _ids_of(own, scene.ego.box_ids) if g >= 0}
        gc = {int(g) for g in _ids_of(other, scene.cav.box_ids) if g >= 0} if fused else set()
        gt = [g for g in sorted(ge | gc) if str(g) in pos]
        P = np.array([pos[str(g)] for g in gt], float).reshape(-1, 2)
        tracks = list(objects.tracks) if objects is not None else []
        X = np.array([t.x[:2] for t in tracks], float).reshape(-1, 2)
        D = np.linalg.norm(P[:, None] - X[None], axis=2) if len(gt) and len(tracks) else np.zeros((len(gt), len(tracks)))
        lim = np.maximum(self.max_distance_m, self.max_distance_rel * np.linalg.norm(P, axis=1))
        col = {t.id: j for j, t in enumerate(tracks)}
        match: dict[int, int] = {}
        for i, g in enumerate(gt):
            j = col.get(self._last.get(g, -1))
            if j is not None and D[i, j] < lim[i]:
                match[i] = j
        rows = [i for i in range(len(gt)) if i not in match]
        cols = [j for j in range(len(tracks)) if j not in match.values()]
        if rows and cols:
            C = D[np.ix_(rows, cols)]
            ok = C < lim[rows][:, None]
            for a, b in zip(*linear_sum_assignment(np.where(ok, C, 1e6))):
                if ok[a, b]:
                    match[rows[a]] = cols[b]
        updated = {j for j, t in enumerate(tracks) if t.last_update == objects.stamp} if objects is not None else set()
        out = {"objects": len(gt), "matched": len(match), "id_switches": 0,
               "false_tracks": len(updated - set(match.values())), "velocity_errors": [], "two_view_errors": []}
        for i, j in match.items():
            g, t = gt[i], tracks[j].id
            if g in self._last and self._last[g] != t:
                out["id_switches"] += 1
            self._last[g] = t
            if g in ge and g in gc and str(g) in vel:
                out["velocity_errors"].append(float(np.hypot(*(tracks[j].x[2:] - np.asarray(vel[str(g)], float)))))
        if fused and len(result.pairs):
            v, ok = two_view_velocities(own, other, result.T_ego_cav[:2, :2], result.pairs)
            ids = _ids_of(own, scene.ego.box_ids)
            for (i, _), vv, o in zip(np.asarray(result.pairs, int), v, ok):
                g = int(ids[i])
                if o and g >= 0 and str(g) in vel:
                    out["two_view_errors"].append(float(np.hypot(*(vv - np.asarray(vel[str(g)], float)))))
        return out


def objects_report(frames: list[dict]) -> dict:
    """Sum of per-frame object figures (`ObjectScore.add`): {"frames", "objects", "matched_share",
    "id_switches", "id_switches_per_100_frames", "false_tracks_per_frame", "velocity_error_mps":
    {"n", "median", "p90"}, "two_view_velocity_error_mps": {...}}."""
    n = len(frames)
    total = {k: sum(f[k] for f in frames) for k in ("objects", "matched", "id_switches", "false_tracks")}
    return {"frames": n, "objects": total["objects"],
            "matched_share": total["matched"] / total["objects"] if total["objects"] else None,
            "id_switches": total["id_switches"],
            "id_switches_per_100_frames": 100.0 * total["id_switches"] / n if n else None,
            "false_tracks_per_frame": total["false_tracks"] / n if n else None,
            "velocity_error_mps": _stats([e for f in frames for e in f["velocity_errors"]]),
            "two_view_velocity_error_mps": _stats([e for f in frames for e in f["two_view_errors"]])}
