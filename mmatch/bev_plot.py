"""Bird's-eye picture of one fused frame pair (OpenCV drawing, no plotting library needed).

Ego points blue, CAV points orange after the estimated transform, the CAV points under
the true transform as a faint ghost, matched pairs joined by green lines, the two radars
as triangles. Ego radar frame: x right, y forward (up in the picture).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mmatch.types import Scene

BLUE, ORANGE, GHOST, GREEN, WHITE, GREY = (220, 120, 30), (30, 140, 255), (90, 90, 90), (60, 200, 60), \
    (255, 255, 255), (160, 160, 160)


def draw_bev(scene: Scene, T_est: np.ndarray | None, own_centres: np.ndarray, other_centres: np.ndarray,
             pairs: np.ndarray, path: str | Path, size_px: int = 900, span_m: float = 120.0) -> None:
    """Write a PNG. own_centres / other_centres: (V, 2) vehicle centres in their own radar frames."""
    import cv2

    img = np.full((size_px, size_px, 3), 25, np.uint8)
    scale = size_px / span_m
    origin = np.array([size_px / 2, size_px * 0.8])

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.column_stack([origin[0] + xy[:, 0] * scale, origin[1] - xy[:, 1] * scale]).astype(np.int32)

    def move(T: np.ndarray, xy: np.ndarray) -> np.ndarray:
        return np.asarray(xy, float).reshape(-1, 2) @ T[:2, :2].T + T[:2, 3]

    for gx in range(-60, 61, 10):
        cv2.line(img, tuple(px([gx, -30])[0]), tuple(px([gx, 100])[0]), (40, 40, 40), 1)
    for gy in range(-20, 101, 10):
        cv2.line(img, tuple(px([-60, gy])[0]), tuple(px([60, gy])[0]), (40, 40, 40), 1)
    for p in px(move(scene.gt_T_ego_cav, scene.cav.points[:, :2])):
        cv2.circle(img, tuple(p), 2, GHOST, -1)
    for p in px(scene.ego.points[:, :2]):
        cv2.circle(img, tuple(p), 2, BLUE, -1)
    if T_est is not None:
        for p in px(move(T_est, scene.cav.points[:, :2])):
            cv2.circle(img, tuple(p), 2, ORANGE, -1)
        a, b = px(own_centres), px(move(T_est, other_centres))
        for i, j in pairs:
            cv2.circle(img, tuple(a[i]), 9, GREEN, 1)
            cv2.circle(img, tuple(b[j]), 9, GREEN, 1)
            cv2.line(img, tuple(a[i]), tuple(b[j]), GREEN, 2)
    for T, colour in ((np.eye(4), BLUE), (scene.gt_T_ego_cav, GHOST), (T_est, ORANGE)):
        if T is None:
            continue
        tri = px(move(T, np.array([[0, 2.5], [-1.2, -1.0], [1.2, -1.0]])))
        cv2.fillPoly(img, [tri], colour)
    cv2.putText(img, "ego points", (10, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, BLUE, 1)
    cv2.putText(img, "CAV points, estimated transform", (10, 40), cv2.FONT_HERSHEY_SIMPLEX, 0.5, ORANGE, 1)
    cv2.putText(img, "CAV points, true transform", (10, 60), cv2.FONT_HERSHEY_SIMPLEX, 0.5, GREY, 1)
    cv2.putText(img, "matched vehicles", (10, 80), cv2.FONT_HERSHEY_SIMPLEX, 0.5, GREEN, 1)
    cv2.putText(img, f"{scene.name}  grid 10 m", (10, size_px - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, WHITE, 1)
    cv2.imwrite(str(path), img)
