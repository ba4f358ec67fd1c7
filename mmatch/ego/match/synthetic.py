"""Synthetic dense-traffic frame pairs: two views of 10-45 vehicles each, with ground truth.

The simulator's front cameras see at most 12-15 vehicles however dense the traffic
(occlusion), so frame pairs of 30-40 vehicles a view are drawn here from a simple model of
the same kind: vehicles on a ten-lane road, each seen by a radar within +-55 deg and 80 m
(90 % detected), 2-8 points on its near face (0.5 m across, 0.1 m range noise, Doppler
from the relative velocity), a camera centre with 8 % depth noise and 0.6 deg bearing
noise, a box of its height at its depth, the simulator's synthetic descriptors, and
guardrail posts as the stationary background. The CAV drives the same way 15-40 m ahead of
the Ego or towards it 90-120 m ahead. Used by `mmatch bench` (suite rmnet), the RM-net
tests, and optionally by `mmatch train` (--synthetic-scenes).
"""

from __future__ import annotations


import numpy as np

from mmatch.shared import CANONICAL_FOCAL_PX, SharedFrame


def _rot(yaw: float) -> np.ndarray:
    return np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])


def _view(rng, pose_xy, heading, vel_world, veh_xy, veh_vel, colours, heights, posts, sender):
    """One radar's SharedFrame of the synthetic world; returns (frame, world vehicle id per vehicle).

    The radar sits at pose_xy facing `heading` (rad from world +x); its frame's x axis points
    at heading - 90 deg (right), y along the heading.
    """
    from mmatch.sim.camera import synth_descriptors

    R = _rot(heading - np.pi / 2)                                      # world_R_radar

    def to_local(v):
        return v @ R                                                   # rows: R^T v

    local = to_local(veh_xy - pose_xy)
    rng_m = np.linalg.norm(local, axis=1)
    az = np.arctan2(local[:, 0], local[:, 1])
    seen = np.flatnonzero((rng_m > 3) & (rng_m < 80) & (np.abs(az) < np.radians(55)) & (rng.random(len(local)) < 0.9))
    v_own = to_local(vel_world)
    pts, idx, centres, boxes = [], [], [], []
    for k, vid in enumerate(seen):
        c = local[vid]
        u = c / np.linalg.norm(c)
        n = np.array([-u[1], u[0]])
        m = int(rng.integers(2, 9))
        p = c - 1.4 * u + rng.normal(0, 0.5, (m, 1)) * n + rng.normal(0, 0.1, (m, 1)) * u
        uu = p / np.linalg.norm(p, axis=1, keepdims=True)
        dop = (uu @ (to_local(veh_vel[vid]) - v_own)) + rng.normal(0, 0.1, m)
        pts.append(np.column_stack([p, rng.uniform(-0.3, 1.2, m), dop, rng.uniform(8, 20, m)]))
        idx.append(np.full(m, k))
        depth = np.linalg.norm(c) * (1 + rng.normal(0, 0.08))
        b = np.arctan2(c[0], c[1]) + rng.normal(0, 0.01)
        centres.append([depth * np.sin(b), depth * np.cos(b)])
        h_px, w_px = CANONICAL_FOCAL_PX * heights[vid] / depth, CANONICAL_FOCAL_PX * 4.5 / depth
        u0 = CANONICAL_FOCAL_PX * np.tan(b)                     # canonical image (shared.py)
        boxes.append([u0 - w_px / 2, -h_px / 2, u0 + w_px / 2, h_px / 2, rng.uniform(0.6, 0.95), depth])
    bg = to_local(posts - pose_xy) if len(posts) else np.zeros((0, 2))
    bg = bg[(np.linalg.norm(bg, axis=1) < 90) & (np.abs(np.arctan2(bg[:, 0], bg[:, 1])) < np.radians(60))]
    bg = bg + rng.normal(0, 0.1, bg.shape)
    feats = synth_descriptors(rng, colours[seen], 1.0, np.zeros(len(seen)))
    V = len(seen)
    frame = SharedFrame(
        sender=sender, seq=0, stamp=0.0, radar_height=0.6, ego_velocity=v_own,
        vehicle_points=np.vstack(pts).astype(np.float32) if pts else np.zeros((0, 5), np.float32),
        vehicle_index=np.concatenate(idx).astype(np.int32) if idx else np.zeros(0, np.int32),
        vehicle_boxes=np.array(boxes, np.float32).reshape(-1, 6), vehicle_box_index=np.arange(V, dtype=np.int32),
        vehicle_centers=np.array(centres, np.float32).reshape(-1, 2), vehicle_features=feats.astype(np.float32),
        background=np.column_stack([bg, np.full(len(bg), 0.5)]).astype(np.float32))
    return frame, seen


def dense_pair(seed: int, per_view: int = 40) -> tuple[SharedFrame, SharedFrame, np.ndarray, np.ndarray]:
    """(own, other, gt pairs (P, 2) of vehicle indices, T_ego_cav 4x4) with about per_view vehicles a view."""
    rng = np.random.default_rng([seed, 4040])
    lanes = 10
    xs = (np.arange(lanes) - (lanes - 1) / 2) * 3.5
    n_world = int(per_view * 2.2)
    pos: list[np.ndarray] = []
    tries = 0
    while len(pos) < n_world and tries < 200 * n_world:  # a full road takes what fits (10 lanes x 140 m)
        tries += 1
        p = np.array([rng.choice(xs) + rng.normal(0, 0.2), rng.uniform(-30, 110)])
        if all(np.hypot(*(p - q)) > 5.0 for q in pos) and np.hypot(*p) > 6:
            pos.append(p)
    veh = np.array(pos)
    direction = np.where(veh[:, 0] > 0, 1.0, -1.0)
    speed = rng.uniform(8, 20, len(veh))
    vel = np.column_stack([np.zeros(len(veh)), direction * speed])
    colours = rng.choice(8, len(veh), p=[0.22, 0.14, 0.1, 0.2, 0.1, 0.1, 0.07, 0.07])
    heights = np.where(rng.random(len(veh)) < 0.85, rng.uniform(1.4, 1.8, len(veh)), rng.uniform(2.8, 3.6, len(veh)))
    posts = np.vstack([np.column_stack([np.full(150, side * 20.0), np.arange(-40, 110, 1.0)]) for side in (-1, 1)])
    ego_xy, ego_yaw = np.array([xs[6], -20.0]), np.pi / 2
    if rng.random() < 0.5:
        cav_xy, cav_yaw = np.array([xs[int(rng.integers(5, 10))], rng.uniform(-5, 20)]), np.pi / 2
    else:
        cav_xy, cav_yaw = np.array([xs[int(rng.integers(0, 5))], rng.uniform(70, 100)]), -np.pi / 2
    cav_xy = cav_xy + rng.normal(0, 0.3, 2)
    cav_yaw += rng.normal(0, 0.02)
    v_ego = np.array([np.cos(ego_yaw), np.sin(ego_yaw)]) * 12.0
    v_cav = np.array([np.cos(cav_yaw), np.sin(cav_yaw)]) * 12.0
    own, seen_a = _view(rng, ego_xy, ego_yaw, v_ego, veh, vel, colours, heights, posts, "ego")
    other, seen_b = _view(rng, cav_xy, cav_yaw, v_cav, veh, vel, colours, heights, posts, "cav")
    common = np.intersect1d(seen_a, seen_b)
    gt = np.column_stack([np.searchsorted(seen_a, common), np.searchsorted(seen_b, common)]).astype(np.int32)
    T = np.eye(4)
    T[:2, :2] = _rot(cav_yaw - ego_yaw)
    T[:2, 3] = (cav_xy - ego_xy) @ _rot(ego_yaw - np.pi / 2)
    return own, other, gt, T
