"""How hard a set of scenes is, measured from their ground-truth labels (issue 2 "done when").

Figures: points per frame; radar points per moving vehicle (vehicles with at least one
point); the share of vehicles with two points or fewer; the share of noise and ghost
points; for vehicles seen by both radars, the distance between their two point
centroids after the true transform; how often the nearest appearance descriptor is the
true partner. Issue 10 adds what angle noise and false detections do: the median
|residual| of a stationary Doppler fit on the background points, the mean share of a
vehicle's points that project inside its own box, false detections per frame, and the
share of scenes with fewer than two co-visible pairs.
"""

from __future__ import annotations

import numpy as np

from mmatch.types import Scene

TARGETS = {
    "median_points_per_frame": (100, 350),
    "median_points_per_moving_vehicle": (None, 6),
    "share_vehicles_le2_points": (0.10, None),
    "noise_ghost_share": (0.03, 0.15),
    "median_covisible_centroid_distance_m": (1.0, None),
    "descriptor_nn_true_share": (None, 0.75),
    "median_background_doppler_residual_mps": (0.12, None),
    "mean_points_in_own_box_share": (0.80, 0.92),
    "false_detections_per_frame": (0.5, 1.0),
    "share_scenes_lt2_covisible": (0.05, 0.15),
}


def _background_residual(view) -> np.ndarray:
    """|doppler - fitted stationary doppler| (m/s) of the background points (least squares on them)."""
    bg = view.points[view.point_labels == -1]
    if len(bg) < 3:
        return np.zeros(0)
    r = np.linalg.norm(bg[:, :3], axis=1)
    A = -bg[:, :2] / np.maximum(r, 1e-6)[:, None]
    v, *_ = np.linalg.lstsq(A.astype(float), bg[:, 3].astype(float), rcond=None)
    return np.abs(bg[:, 3] - A @ v)


def _in_own_box(view) -> list[float]:
    """Per vehicle with a box and points: the share of its points projecting inside its box's
    columns (u1 <= u <= u2; the radar's elevation is too coarse to count: a degree or two is
    half a car's height at 30 m, and the CAV side's wedge test is horizontal too)."""
    if view.box_ids is None or len(view.points) == 0:
        return []
    T, K = view.camera.T_cam_radar, view.camera.K
    pc = view.points[:, :3].astype(float) @ T[:3, :3].T + T[:3, 3]
    front = pc[:, 2] > 0.3
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
    out = []
    for b, vid in enumerate(view.box_ids):
        if vid < 0:
            continue
        mine = view.point_labels == vid
        if not mine.any():
            continue
        u1, u2 = view.boxes[b, 0], view.boxes[b, 2]
        inside = front[mine] & (uv[mine, 0] >= u1) & (uv[mine, 0] <= u2)
        out.append(float(inside.mean()))
    return out


def realism_figures(scenes: list[Scene]) -> dict[str, float]:
    """The realism figures over scenes that carry the optional label keys."""
    per_frame, per_vehicle, noise, total, cdist = [], [], 0, 0, []
    nn_hits, nn_total = 0, 0
    residual, in_box, false_det, views, few = [], [], 0, 0, 0
    for s in scenes:
        few += int(len(s.gt_pairs) < 2)
        parked = set(s.meta.get("parked_ids", []))
        cents = {}
        for side, view in (("ego", s.ego), ("cav", s.cav)):
            lab = view.point_labels
            if lab is None:
                continue
            per_frame.append(len(lab))
            if s.meta.get("stopped") != side:     # angle noise shows in the Doppler of a moving radar only
                residual.append(_background_residual(view))
            in_box.extend(_in_own_box(view))
            if view.box_ids is not None:
                false_det += int(np.sum(view.box_ids < 0))
                views += 1
            noise += int(np.sum(lab == -2))
            total += len(lab)
            ids, counts = np.unique(lab[lab >= 0], return_counts=True)
            moving = np.array([i not in parked for i in ids], bool)
            per_vehicle.extend(counts[moving].tolist())
            cents[side] = {int(i): view.points[lab == i, :3].mean(0) for i in ids[moving]}
        if "ego" in cents and "cav" in cents:
            T = s.gt_T_ego_cav
            for vid, c_cav in cents["cav"].items():
                if vid in cents["ego"]:
                    cdist.append(float(np.linalg.norm((T[:3, :3] @ c_cav + T[:3, 3])[:2] - cents["ego"][vid][:2])))
        if len(s.gt_pairs) and len(s.cav.features):
            d = np.linalg.norm(s.ego.features[:, None] - s.cav.features[None], axis=2)
            for i, j in s.gt_pairs:
                nn_hits += int(np.argmin(d[i]) == j)
                nn_total += 1
    pv = np.array(per_vehicle)
    return {
        "scenes": len(scenes),
        "median_points_per_frame": float(np.median(per_frame)) if per_frame else float("nan"),
        "median_points_per_moving_vehicle": float(np.median(pv)) if len(pv) else float("nan"),
        "share_vehicles_le2_points": float(np.mean(pv <= 2)) if len(pv) else float("nan"),
        "noise_ghost_share": noise / total if total else float("nan"),
        "median_covisible_centroid_distance_m": float(np.median(cdist)) if cdist else float("nan"),
        "descriptor_nn_true_share": nn_hits / nn_total if nn_total else float("nan"),
        "median_background_doppler_residual_mps": float(np.median(np.concatenate(residual)))
        if residual and sum(map(len, residual)) else float("nan"),
        "mean_points_in_own_box_share": float(np.mean(in_box)) if in_box else float("nan"),
        "false_detections_per_frame": false_det / views if views else float("nan"),
        "share_scenes_lt2_covisible": few / len(scenes) if scenes else float("nan"),
    }


def check_targets(fig: dict[str, float]) -> dict[str, bool]:
    """Which figures fall inside the target bands (issues 2 and 10)."""
    out = {}
    for key, (lo, hi) in TARGETS.items():
        v = fig[key]
        out[key] = bool(np.isfinite(v) and (lo is None or v >= lo) and (hi is None or v <= hi))
    return out
