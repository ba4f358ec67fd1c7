"""How hard a set of scenes is, measured from their ground-truth labels (issue 2 "done when").

Figures: points per frame; radar points per moving vehicle (vehicles with at least one
point); the share of vehicles with two points or fewer; the share of noise and ghost
points; for vehicles seen by both radars, the distance between their two point
centroids after the true transform; how often the nearest appearance descriptor is the
true partner.
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
}


def realism_figures(scenes: list[Scene]) -> dict[str, float]:
    """The realism figures over scenes that carry the optional label keys."""
    per_frame, per_vehicle, noise, total, cdist = [], [], 0, 0, []
    nn_hits, nn_total = 0, 0
    for s in scenes:
        parked = set(s.meta.get("parked_ids", []))
        cents = {}
        for side, view in (("ego", s.ego), ("cav", s.cav)):
            lab = view.point_labels
            if lab is None:
                continue
            per_frame.append(len(lab))
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
    }


def check_targets(fig: dict[str, float]) -> dict[str, bool]:
    """Which figures fall inside the target bands of issue 2."""
    out = {}
    for key, (lo, hi) in TARGETS.items():
        v = fig[key]
        out[key] = bool(np.isfinite(v) and (lo is None or v >= lo) and (hi is None or v <= hi))
    return out
