"""Shared frames built from a scene's ground-truth labels instead of the CAV pipeline.

`mmatch eval --cav labels` uses them to measure matching and alignment alone, with
perfect separation; they need the optional `V_point_labels` / `V_box_ids` keys.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mmatch.cav.config import InputConfig
from mmatch.cav.egomotion import fit_egomotion
from mmatch.cav.process import moving_sketch, with_size_prior_depth
from mmatch.errors import SceneFormatError
from mmatch.shared import SharedFrame, canonical_boxes
from mmatch.types import View, normalised_descriptors


def shared_from_labels(view: View, sender: str, seq: int = 0) -> SharedFrame:
    """Vehicles = every correctly detected box (parked cars too) with its labelled points; background = label -1;
    the moving sketch = the returns the ego-motion fit calls moving that no shared vehicle owns.
    A box without a depth is placed by the CAV side's size prior (`with_size_prior_depth`), and
    descriptors are made distributions as the CAV side makes them (`normalised_descriptors`)."""
    if view.point_labels is None or view.box_ids is None:
        raise SceneFormatError("<scene>", "point_labels/box_ids", "labels needed for --cav labels")
    lab, ids = view.point_labels, view.box_ids
    view = replace(view, boxes=with_size_prior_depth(np.asarray(view.boxes, np.float32), view.camera.K,
                                                     InputConfig().unknown_depth_height_m))
    keep = [b for b, vid in enumerate(ids) if vid >= 0]
    pts, idx, centers = [], [], []
    for v, b in enumerate(keep):
        p = view.points[lab == ids[b]]
        pts.append(p)
        idx.append(np.full(len(p), v, np.int32))
        centers.append(_box_centre(view, b))
    bg = view.points[lab == -1, :3]
    ego = fit_egomotion(view.points)
    return SharedFrame(
        sender=sender, seq=seq, stamp=view.stamp, radar_height=view.radar_height,
        ego_velocity=ego.velocity if ego.ok else np.full(2, np.nan),
        vehicle_points=np.vstack(pts).astype(np.float32) if pts else np.zeros((0, 5), np.float32),
        vehicle_index=np.concatenate(idx) if idx else np.zeros(0, np.int32),
        vehicle_boxes=canonical_boxes(view.boxes[keep], view.camera.K),
        vehicle_box_index=np.array(keep, np.int32),
        vehicle_centers=np.array(centers, np.float32).reshape(-1, 2),
        vehicle_features=normalised_descriptors(view.features[keep]),
        background=bg.astype(np.float32),
        moving=moving_sketch(view.points, ego.moving & ~np.isin(lab, np.asarray(ids)[keep])))


def _box_centre(view: View, b: int) -> np.ndarray:
    """x, y (radar frame) of a box's centre ray at its depth."""
    u = (view.boxes[b, 0] + view.boxes[b, 2]) / 2
    v = (view.boxes[b, 1] + view.boxes[b, 3]) / 2
    ray = np.linalg.solve(view.camera.K, np.array([u, v, 1.0]))
    cam = ray / np.linalg.norm(ray) * view.boxes[b, 5]
    radar = np.linalg.inv(view.camera.T_cam_radar) @ np.append(cam, 1.0)
    return radar[:2]
