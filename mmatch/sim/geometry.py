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


def turned(p: np.ndarray, angle: float) -> np.ndarray:
    """Points p (..., 2) turned counter-clockwise about the origin by `angle` rad."""
    c, s = np.cos(angle), np.sin(angle)
    p = np.asarray(p, float)
    return np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], axis=-1)


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


_SORTED_FROM = 64       # targets from which segments_block tests only the pairs whose bearings overlap


def segments_block(origin: np.ndarray, targets: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray,
                   ignore: np.ndarray | None = None) -> np.ndarray:
    """Which rays origin->target (N targets) cross any segment a-b (S segments) before the target.

    ignore: optional bool (N, S), True where a segment must not count for a target (its own box).
    Returns bool (N,). With many targets only the (target, segment) pairs whose bearings
    overlap are tested (`_bearing_pairs`): the same answer as testing all N x S.
    """
    if len(targets) == 0 or len(seg_a) == 0:
        return np.zeros(len(targets), bool)
    d = targets - origin                           # (N, 2)
    if len(targets) < _SORTED_FROM:                # all pairs at once
        hit = _crosses(d[:, None], (seg_a - origin)[None], (seg_b - seg_a)[None])
        if ignore is not None:
            hit &= ~ignore
        return hit.any(axis=1)
    n, s = _bearing_pairs(d, seg_a - origin, seg_b - origin)
    if ignore is not None:
        keep = ~ignore[n, s]
        n, s = n[keep], s[keep]
    out = np.zeros(len(targets), bool)
    out[n[_crosses(d[n], seg_a[s] - origin, seg_b[s] - seg_a[s])]] = True
    return out


def _crosses(d: np.ndarray, ao: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Whether the ray origin + t d (0 < t < 1) crosses the segment ao + u e (0 <= u <= 1):
    d, ao, e (..., 2) relative to the origin, broadcast against each other."""
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ao[..., 0] * e[..., 1] - ao[..., 1] * e[..., 0]) / denom
        u = (ao[..., 0] * d[..., 1] - ao[..., 1] * d[..., 0]) / denom
    return (np.abs(denom) > 1e-9) & (t > 1e-6) & (t < 1 - 1e-3) & (u >= 0) & (u <= 1)


def _bearing_pairs(d: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(target, segment) index pairs whose bearings from the origin overlap: d (N, 2) targets,
    a, b (S, 2) segment ends, all relative to the origin. A ray can only cross a segment at
    the ray's own bearing, which lies in the segment's bearing interval; the intervals are
    widened by 1e-6 rad against rounding, and a segment through or next to the origin spans
    every bearing."""
    ang = np.arctan2(d[:, 1], d[:, 0])
    order = np.argsort(ang, kind="stable")
    sorted_ang = ang[order]
    ang_a = np.arctan2(a[:, 1], a[:, 0])
    span = (np.arctan2(b[:, 1], b[:, 0]) - ang_a + np.pi) % (2 * np.pi) - np.pi
    lo = (ang_a + np.minimum(span, 0.0) - 1e-6 + np.pi) % (2 * np.pi) - np.pi
    hi = lo + np.abs(span) + 2e-6
    near = np.minimum(np.hypot(a[:, 0], a[:, 1]), np.hypot(b[:, 0], b[:, 1])) < 1e-3
    every = (np.abs(span) > np.pi - 0.02) | near
    lo, hi = np.where(every, -4.0, lo), np.where(every, 4.0, hi)
    seg = np.arange(len(a))
    wraps = hi > np.pi                             # the part past +pi continues from -pi
    seg = np.concatenate([seg, seg[wraps]])
    lo = np.concatenate([lo, np.full(int(wraps.sum()), -np.pi - 1e-9)])
    hi = np.concatenate([hi, hi[wraps] - 2 * np.pi])
    i0 = np.searchsorted(sorted_ang, lo, side="left")
    i1 = np.searchsorted(sorted_ang, hi, side="right")
    count = np.maximum(i1 - i0, 0)
    s = np.repeat(seg, count)
    pos = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count - i0, count)
    n = order[pos]
    return n, s
