"""What each scene file is, for the breakdowns: co-visible vehicles, vehicles per view, road, direction."""

from __future__ import annotations

import numpy as np

from mmatch.errors import SceneFormatError


def _seen(box_ids: np.ndarray | None, boxes: np.ndarray) -> int:
    """Vehicles a camera detects: boxes of a real vehicle (ids >= 0) when labelled, else every box."""
    return int((box_ids >= 0).sum()) if box_ids is not None else len(boxes)


def scene_facts(path: str) -> dict | None:
    """{"co_visible", "ego_vehicles", "cav_vehicles", "vehicles_per_view", "road", "relation", "physics"}
    of one file (None when it breaks the format; the evaluation names the reason).

    co_visible: ground-truth pairs; vehicles_per_view: the mean of the two views' detected
    vehicles, rounded down; road / relation / physics: from `meta` ("unknown" when absent).
    """
    from mmatch.scene_io import load_scene
    try:
        s = load_scene(path)
    except SceneFormatError:
        return None
    e, c = _seen(s.ego.box_ids, s.ego.boxes), _seen(s.cav.box_ids, s.cav.boxes)
    meta = s.meta if isinstance(s.meta, dict) else {}
    return {"co_visible": len(s.gt_pairs), "ego_vehicles": e, "cav_vehicles": c,
            "vehicles_per_view": (e + c) // 2, "road": str(meta.get("road", "unknown")),
            "relation": str(meta.get("relation", "unknown")),
            "physics": str(meta.get("physics", "unknown"))}
