"""Two shared frames of one synthetic world under a known T_ego_cav (exact, or with noise)."""

from __future__ import annotations

import numpy as np

from mmatch.shared import SharedFrame


def world(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Background (B, 2): an L of walls, poles and scattered clutter; vehicle centres (4, 2); Ego frame, m."""
    wall1 = np.column_stack([np.full(80, -9.0), np.linspace(5, 85, 80)])
    wall2 = np.column_stack([np.linspace(-9, 30, 40), np.full(40, 70.0)])
    poles = np.array([[8.0, 20.0], [8.5, 45.0], [-3.0, 58.0], [20.0, 35.0]])
    clutter = rng.uniform([-20.0, 0.0], [30.0, 90.0], (60, 2))
    bg = np.vstack([wall1, wall2, poles, clutter])
    cars = np.array([[-3.0, 25.0], [3.5, 40.0], [-2.0, 52.0], [4.0, 62.0]])
    return bg + rng.normal(0, 0.02, bg.shape), cars


def T_se2(yaw_deg: float, tx: float, ty: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:2, 3] = tx, ty
    return T


def frame(sender: str, bg: np.ndarray, cars: np.ndarray, T_frame_world: np.ndarray,
          rng: np.random.Generator, pts_per_car: int = 5) -> SharedFrame:
    """The world seen from a radar at T_frame_world (maps Ego-world xy into this frame)."""
    move = lambda xy: xy @ T_frame_world[:2, :2].T + T_frame_world[:2, 3]     # noqa: E731
    offsets = rng.normal(0, 0.4, (len(cars), pts_per_car, 2))
    vp = move((cars[:, None, :] + offsets).reshape(-1, 2))
    V = len(cars)
    return SharedFrame(
        sender=sender, seq=0, stamp=0.0, radar_height=0.8, ego_velocity=np.array([0.0, 10.0]),
        vehicle_points=np.column_stack([vp, np.zeros((len(vp), 3))]).astype(np.float32),
        vehicle_index=np.repeat(np.arange(V), pts_per_car).astype(np.int32),
        vehicle_boxes=np.tile(np.array([0, 0, 10, 10, 0.9, 20], np.float32), (V, 1)),
        vehicle_box_index=np.arange(V, dtype=np.int32),
        vehicle_centers=move(cars).astype(np.float32),
        vehicle_features=np.full((V, 32), 1 / 16, np.float32),
        background=np.column_stack([move(bg), np.zeros(len(bg))]).astype(np.float32))


def pair_of_frames(T_ego_cav: np.ndarray, seed: int = 0) -> tuple[SharedFrame, SharedFrame]:
    rng = np.random.default_rng(seed)
    bg, cars = world(rng)
    own = frame("ego", bg, cars, np.eye(4), rng)
    other = frame("cav", bg, cars, np.linalg.inv(T_ego_cav), rng)
    return own, other
