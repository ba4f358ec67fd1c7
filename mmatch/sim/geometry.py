"""Small 2-D/3-D geometry helpers for the simulator (world frame: x east, y north, z up, m)."""

from __future__ import annotations

import numpy as np


def pose_matrix(xy: np.ndarray, yaw: float, z: float) -> np.ndarray:
    """world_T_sensor for a sensor at (x, y, z) whose forward (+y of the sensor) points at angle `yaw`.

    yaw is measured from world +x, counter-clockwise (rad). Sensor axes: x right, y forward, z up.
    """
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, 0] = (s, -c, 0.0)   # right
    T[:3, 1] = (c, s, 0.0)    # forward
    T[:3, 2] = (0.0, 0.0, 1.0)
    T[:3, 3] = (xy[0], xy[1], z)
    return T


def transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    return pts @ T[:3, :3].T + T[:3, 3]


def box_corners(center: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """BEV corners (V, 4, 2) of oriented boxes, ordered front-left, front-right, rear-right, rear-left."""
    f = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    r = np.stack([np.sin(yaw), -np.cos(yaw)], -1)
    hl, hw = (length / 2)[:, None], (width / 2)[:, None]
    return np.stack([center + f * hl - r * hw, center + f * hl + r * hw,
                     center - f * hl + r * hw, center - f * hl - r * hw], axis=1)


def segments_block(origin: np.ndarray, targets: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray,
                   ignore: np.ndarray | None = None) -> np.ndarray:
    """Which rays origin->target (N targets) cross any segment a-b (S segments) before the target.

    ignore: optional bool (N, S), True where a segment must not count for a target (its own box).
    Returns bool (N,).
    """
    if len(targets) == 0 or len(seg_a) == 0:
        return np.zeros(len(targets), bool)
    d = targets - origin                           # (N, 2)
    e = seg_b - seg_a                              # (S, 2)
    ao = seg_a - origin                            # (S, 2)
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ao[None, :, 0] * e[None, :, 1] - ao[None, :, 1] * e[None, :, 0]) / denom
        u = (ao[None, :, 0] * d[:, None, 1] - ao[None, :, 1] * d[:, None, 0]) / denom
    hit = (np.abs(denom) > 1e-9) & (t > 1e-6) & (t < 1 - 1e-3) & (u >= 0) & (u <= 1)
    if ignore is not None:
        hit &= ~ignore
    return hit.any(axis=1)
