"""Bird's-eye picture of one aligned frame pair (matplotlib, `plots` extra), in the Ego radar frame.

Drawn: both radar clouds after alignment (Ego points; CAV points under the estimated
transform; the CAV points under the true transform as hollow grey rings, so every
misplaced point shows its error), each camera's field-of-view wedge (the CAV's placed by
the estimate), each camera detection as a footprint (its bearing extent at its depth,
about a car deep), the matched pairs joined (green: a true pair, red: a false one), both
radars as triangles (the CAV's where the estimate and where the truth put it, joined by
the translation error) and RTE / RRE in the title. Axes: x right, y forward, metres, equal
scale, fitted to everything drawn but the wedges.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mmatch.cav.frustum import box_rays
from mmatch.metrics import is_success, rre_deg, rte_m
from mmatch.types import CameraModel, Scene

EGO, CAV, TRUTH, GOOD, BAD = "#1f5fbf", "#e6740f", "#8a8a8a", "#2ca02c", "#d62728"
FOOTPRINT_HALF_DEPTH_M = 1.2


def _move(T: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return np.asarray(xy, float).reshape(-1, 2) @ T[:2, :2].T + T[:2, 3]


def fov_wedge(camera: CameraModel, range_m: float, steps: int = 24) -> np.ndarray:
    """(steps + 1, 2) polygon of a camera's horizontal field of view, radar frame, out to range_m."""
    w, _ = camera.image_size
    cy = float(camera.K[1, 2])
    edges = np.array([[0.0, cy, 0.0, cy, 1.0, 1.0], [w, cy, w, cy, 1.0, 1.0]], np.float64)
    origin, dirs = box_rays(edges, camera)
    a0, a1 = np.arctan2(dirs[:, 1], dirs[:, 0])
    a1 = a0 + (a1 - a0 + np.pi) % (2 * np.pi) - np.pi
    ang = np.linspace(a0, a1, steps)
    arc = origin[:2] + range_m * np.column_stack([np.cos(ang), np.sin(ang)])
    return np.vstack([origin[:2], arc])


def footprints(boxes: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Detections on the ground: (M, 4, 2) quads (bearing extent at the box depth, a car deep) and (M, 2) centres."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 6)
    if len(boxes) == 0:
        return np.zeros((0, 4, 2)), np.zeros((0, 2))
    left, right = boxes.copy(), boxes.copy()
    left[:, 2], right[:, 0] = boxes[:, 0], boxes[:, 2]
    origin, d_mid = box_rays(boxes, camera)
    _, d_l = box_rays(left, camera)
    _, d_r = box_rays(right, camera)
    depth = boxes[:, 5:6]
    o = origin[None, :2]
    pl, pr, centre = o + d_l[:, :2] * depth, o + d_r[:, :2] * depth, o + d_mid[:, :2] * depth
    u = d_mid[:, :2] * FOOTPRINT_HALF_DEPTH_M
    quads = np.stack([pl - u, pr - u, pr + u, pl + u], axis=1)
    return quads, centre


def _triangle(T: np.ndarray, size: float) -> np.ndarray:
    return _move(T, np.array([[0.0, 1.2], [-0.6, -0.5], [0.6, -0.5]]) * size)


def draw_bev(scene: Scene, T_est: np.ndarray | None, box_pairs: np.ndarray, path: str | Path,
             method: str = "", formats: Sequence[str] = ("png",), size_in: float = 7.0,
             dpi: int = 100) -> list[Path]:
    """Write PATH.<format> for each format; returns the files.

    T_est: the estimated T_ego_cav (4x4) or None (no estimate: the CAV is drawn at the truth
    only); box_pairs: (P, 2) predicted pairs as (ego box, cav box) indices of the scene file.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Polygon

    from mmatch.report.plots import pyplot, save_figure

    plt = pyplot()
    gt = scene.gt_T_ego_cav
    e, c = scene.ego, scene.cav
    ego_xy = e.points[:, :2].astype(float)
    cav_true = _move(gt, c.points[:, :2])
    cav_est = _move(T_est, c.points[:, :2]) if T_est is not None else np.zeros((0, 2))
    ego_quads, ego_centres = footprints(e.boxes, e.camera)
    cav_quads, cav_centres = footprints(c.boxes, c.camera)
    T_cav = T_est if T_est is not None else gt

    everything = np.vstack([ego_xy, cav_true, cav_est, np.zeros((1, 2)), gt[None, :2, 3],
                            T_cav[None, :2, 3], ego_centres, _move(T_cav, cav_centres)])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    span = max(float((hi - lo).max()), 20.0)
    mid = (lo + hi) / 2
    half = span / 2 + 0.06 * span
    reach = 3.0 * half

    fig, ax = plt.subplots(figsize=(size_in, size_in * 1.12))
    ax.add_patch(Polygon(fov_wedge(e.camera, reach), closed=True, fc=EGO, alpha=0.06, ec=EGO, lw=0.6))
    ax.add_patch(Polygon(_move(gt, fov_wedge(c.camera, reach)), closed=True, fill=False, ec=TRUTH, lw=0.9,
                         ls="--"))
    if T_est is not None:
        ax.add_patch(Polygon(_move(T_est, fov_wedge(c.camera, reach)), closed=True, fc=CAV, alpha=0.06,
                             ec=CAV, lw=0.6))
    for q in ego_quads:
        ax.add_patch(Polygon(q, closed=True, fill=False, ec=EGO, lw=1.1))
    for q in cav_quads:
        ax.add_patch(Polygon(_move(T_cav, q), closed=True, fill=False, ec=CAV, lw=1.1))
    ax.scatter(cav_true[:, 0], cav_true[:, 1], s=22, facecolors="none", edgecolors=TRUTH, lw=0.7, zorder=3)
    ax.scatter(ego_xy[:, 0], ego_xy[:, 1], s=7, c=EGO, lw=0, zorder=4)
    if T_est is not None:
        ax.scatter(cav_est[:, 0], cav_est[:, 1], s=12, c=CAV, marker="x", lw=0.9, zorder=5)
    truth = {(int(a), int(b)) for a, b in np.asarray(scene.gt_pairs).reshape(-1, 2)}
    right = 0
    moved_centres = _move(T_cav, cav_centres)
    for a, b in np.asarray(box_pairs, int).reshape(-1, 2):
        if a >= len(ego_centres) or b >= len(moved_centres):
            continue
        ok = (int(a), int(b)) in truth
        right += ok
        p, q = ego_centres[a], moved_centres[b]
        ax.plot([p[0], q[0]], [p[1], q[1]], color=GOOD if ok else BAD, lw=2.0, ls="-" if ok else "--", zorder=6)
    tri = span / 45
    ax.add_patch(Polygon(_triangle(np.eye(4), tri), closed=True, fc=EGO, ec="black", lw=0.6, zorder=7))
    ax.add_patch(Polygon(_triangle(gt, tri), closed=True, fc="white", ec=TRUTH, lw=1.2, zorder=7))
    if T_est is not None:
        ax.add_patch(Polygon(_triangle(T_est, tri), closed=True, fc=CAV, ec="black", lw=0.6, zorder=8))
        ax.plot([gt[0, 3], T_est[0, 3]], [gt[1, 3], T_est[1, 3]], color=BAD, lw=1.0, ls=":", zorder=7)

    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m), Ego radar frame, right")
    ax.set_ylabel("y (m), forward")
    head = f"{scene.name}" + (f", {method}" if method else "")
    if T_est is None:
        head += ": no estimate"
    else:
        rre, rte = rre_deg(gt, T_est), rte_m(gt, T_est)
        head += f": {'success' if is_success(rre, rte) else 'failure'}, RTE {rte:.2f} m, RRE {rre:.2f} deg"
    meta = scene.meta if isinstance(scene.meta, dict) else {}
    sub = f"{meta.get('road', '?')} road, CAV {meta.get('relation', '?')} direction, " \
          f"{len(truth)} co-visible, {right}/{len(np.asarray(box_pairs).reshape(-1, 2))} predicted pairs right"
    ax.set_title(head + "\n" + sub)
    glyphs = [
        Line2D([], [], ls="", marker="o", ms=4, mfc=EGO, mec=EGO, label="Ego radar points"),
        Line2D([], [], ls="", marker="x", ms=5, mec=CAV, label="CAV points, estimated transform"),
        Line2D([], [], ls="", marker="o", ms=6, mfc="none", mec=TRUTH, label="CAV points, true transform"),
        Line2D([], [], ls="", marker="s", ms=8, mfc="none", mec=EGO, label="Ego detections (camera)"),
        Line2D([], [], ls="", marker="s", ms=8, mfc="none", mec=CAV, label="CAV detections (estimated)"),
        Line2D([], [], color=GOOD, lw=2, label="matched pair, true"),
        Line2D([], [], color=BAD, lw=2, ls="--", label="matched pair, false"),
        Line2D([], [], ls="", marker="^", ms=8, mfc=EGO, mec="black", label="Ego radar"),
        Line2D([], [], ls="", marker="^", ms=8, mfc=CAV, mec="black", label="CAV radar, estimated"),
        Line2D([], [], ls="", marker="^", ms=8, mfc="white", mec=TRUTH, label="CAV radar, true"),
        Polygon([[0, 0]], fc=EGO, alpha=0.15, ec=EGO, label="Ego camera field of view"),
        Polygon([[0, 0]], fc=CAV, alpha=0.15, ec=CAV, label="CAV camera field of view, estimated"),
        Polygon([[0, 0]], fill=False, ec=TRUTH, ls="--", label="CAV camera field of view, true"),
        Line2D([], [], color=BAD, lw=1, ls=":", label="CAV radar position error"),
    ]
    ax.legend(handles=glyphs, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3, fontsize=7,
              frameon=False)
    return save_figure(fig, Path(path), formats, dpi)
