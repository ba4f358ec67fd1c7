"""A small, self-contained synthetic radar + camera frame for the CAV-side tests.

Everything lives in the radar frame at capture time (x right, y forward, z up, m). The radar
moves over ground at `velocity`; stationary structures (guardrails, facades, poles, parked
cars) show the Doppler of DESIGN.md, moving vehicles show (w - v) projected on the line of
sight. Vehicles return 2-12 points from their visible corners and faces. Noise in azimuth,
elevation and Doppler grows off boresight; clutter and guardrail ghosts are added. The
camera sits 0.3 m above the radar looking forward (OpenCV axes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.types import CameraModel

STATIONARY, NOISE = -1, -2
FOV_AZ = np.radians(60.0)


@dataclass
class SynthFrame:
    points: np.ndarray        # float32 (N, 5)
    labels: np.ndarray        # int32 (N,) vehicle id, -1 stationary, -2 noise/ghost
    moving_ids: np.ndarray    # int32 ids of moving vehicles (others with id >= 0 are parked)
    boxes: np.ndarray         # float32 (M, 6)
    box_ids: np.ndarray       # int32 (M,) vehicle id per box, -1 false detection
    features: np.ndarray      # float32 (M, 32)
    camera: CameraModel
    velocity: np.ndarray      # (2,) radar velocity over ground, radar frame
    centres: np.ndarray       # (V, 2) true vehicle centres
    radar_height: float = 0.8

    @property
    def gt_moving(self) -> np.ndarray:
        return np.isin(self.labels, self.moving_ids)


def make_camera() -> CameraModel:
    K = np.array([[800.0, 0, 640], [0, 800.0, 360], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]   # radar (x r, y f, z up) -> camera (x r, y down, z f)
    T[:3, 3] = [0.0, 0.3, 0.0]                       # camera 0.3 m above the radar (y_cam down)
    return CameraModel(K=K, image_size=(1280, 720), T_cam_radar=T)


def _sigma(lo: float, hi: float, az: np.ndarray) -> np.ndarray:
    return lo + (hi - lo) * np.clip(np.abs(az) / FOV_AZ, 0, 1) ** 2


def _corners(c, yaw, length, width):
    f = np.array([np.cos(yaw), np.sin(yaw)])
    r = np.array([np.sin(yaw), -np.cos(yaw)])
    hl, hw = length / 2, width / 2
    return np.array([c + f * hl - r * hw, c + f * hl + r * hw, c - f * hl + r * hw, c - f * hl - r * hw])


def _vehicle_points(rng, c, yaw, length, width, n):
    """n points on the faces turned to the origin, corners preferred."""
    cs = _corners(c, yaw, length, width)
    cand = []
    for e in range(4):
        a, b = cs[e], cs[(e + 1) % 4]
        normal = np.array([(b - a)[1], -(b - a)[0]])
        normal /= np.linalg.norm(normal)
        mid = (a + b) / 2
        if normal @ (c - mid) > 0:
            normal = -normal
        if normal @ (-mid) <= 0:
            continue
        u = np.concatenate([[0.0, 1.0, 0.0, 1.0], rng.uniform(0, 1, 6)])
        cand.append(a + u[:, None] * (b - a))
    cand = np.vstack(cand)
    pick = rng.choice(len(cand), size=min(n, len(cand)), replace=False)
    return cand[pick] + rng.normal(0, 0.08, (len(pick), 2))


def make_frame(seed: int, n_moving: int = 5, n_parked: int = 2, speed: float | None = None,
               perpendicular: bool = False, clutter: int = 6, ghosts: bool = True) -> SynthFrame:
    """One synthetic frame; `perpendicular` adds a vehicle crossing the line of sight."""
    rng = np.random.default_rng(seed)
    speed = rng.uniform(8, 20) if speed is None else speed
    mount = np.radians(rng.uniform(-5, 5))
    v = speed * np.array([np.sin(mount), np.cos(mount)])    # radar velocity over ground, radar frame
    height = 0.8
    road_half = rng.uniform(6, 12)

    pts, vel, lab = [], [], []
    # guardrails (posts every ~2 m, detection falls with range), facades, poles
    for side in (-1, 1):
        y = np.arange(3.0, 90.0, 2.0) + rng.uniform(0, 2)
        keep = rng.random(len(y)) < 0.6 * np.exp(-y / 45)
        p = np.column_stack([np.full(keep.sum(), side * road_half), y[keep], rng.uniform(-0.5, 0.0, keep.sum())])
        pts.append(p)
        y = np.arange(5.0, 95.0, 1.0)
        keep = rng.random(len(y)) < 0.5 * np.exp(-y / 60)
        p = np.column_stack([np.full(keep.sum(), side * (road_half + 6)) + rng.normal(0, 0.2, keep.sum()),
                             y[keep], rng.uniform(-0.5, 3.0, keep.sum())])
        pts.append(p)
        y = np.arange(8.0, 90.0, 15.0) + rng.uniform(0, 5)
        pts.append(np.column_stack([np.full(len(y), side * (road_half + 1)), y, rng.uniform(0, 2, len(y))]))
    n_static = sum(len(p) for p in pts)
    vel.append(np.zeros((n_static, 2)))
    lab.append(np.full(n_static, STATIONARY))

    # vehicles: moving in lanes, parked at the kerb
    lanes = np.arange(-road_half + 2, road_half - 1.5, 3.5)
    centres, yaws, sizes, speeds = [], [], [], []
    taken = []
    for k in range(n_moving + n_parked + int(perpendicular)):
        parked = n_moving <= k < n_moving + n_parked
        cross = k == n_moving + n_parked
        for _ in range(50):
            if cross:
                c = np.array([rng.uniform(-8, 8), rng.uniform(20, 40)])
                yaw = 0.0 if rng.random() < 0.5 else np.pi
                w = rng.uniform(8, 14)
            elif parked:
                c = np.array([rng.choice([-1, 1]) * (road_half - 1.2), rng.uniform(10, 50)])
                yaw, w = np.pi / 2, 0.0
            else:
                c = np.array([rng.choice(lanes), rng.uniform(8, 65)])
                yaw = np.pi / 2 if rng.random() < 0.6 else -np.pi / 2
                w = rng.uniform(8, 20)
            if all(np.hypot(*(c - t)) > 7 for t in taken):
                break
        taken.append(c)
        centres.append(c)
        yaws.append(yaw)
        sizes.append((rng.uniform(4.0, 5.0), rng.uniform(1.7, 2.0), 1.5))
        speeds.append(w)
    V = len(centres)
    for k in range(V):
        d = np.hypot(*centres[k])
        n = int(np.clip(rng.poisson(1 + 9 * np.exp(-d / 26)), 2, 12))
        xy = _vehicle_points(rng, centres[k], yaws[k], sizes[k][0], sizes[k][1], n)
        z = rng.uniform(0.25, 1.1, len(xy)) - height
        pts.append(np.column_stack([xy, z]))
        w = speeds[k] * np.array([np.cos(yaws[k]), np.sin(yaws[k])])
        vel.append(np.repeat(w[None], len(xy), 0))
        lab.append(np.full(len(xy), k))
        if ghosts and rng.random() < 0.5:     # mirror across the nearer guardrail
            side = np.sign(xy[:1, 0]) if len(xy) else 1
            g = xy[:1].copy()
            g[:, 0] = 2 * side * road_half - g[:, 0]
            pts.append(np.column_stack([g, z[:1]]))
            vel.append(np.array([[-w[0], w[1]]]))
            lab.append(np.full(1, NOISE))
    P = np.vstack(pts)
    W = np.vstack(vel)
    L = np.concatenate(lab).astype(np.int32)
    r = np.linalg.norm(P, axis=1)
    rel = np.column_stack([W - v, np.zeros(len(W))])
    dop = np.einsum("ij,ij->i", rel, P) / r
    az = np.arctan2(P[:, 0], P[:, 1])
    el = np.arcsin(P[:, 2] / r)
    inside = (np.abs(az) < FOV_AZ) & (r > 1.5) & (r < 100)
    r, az, el, dop, L = r[inside], az[inside], el[inside], dop[inside], L[inside]
    # clutter
    c_az = rng.uniform(-1, 1, clutter) * FOV_AZ
    c_stat = -(v[0] * np.sin(c_az) + v[1] * np.cos(c_az))
    c_dop = np.where(rng.random(clutter) < 0.5, c_stat + rng.normal(0, 1.0, clutter), rng.uniform(-20, 20, clutter))
    r = np.concatenate([r, rng.uniform(3, 80, clutter)])
    az = np.concatenate([az, c_az])
    el = np.concatenate([el, rng.normal(0, 0.05, clutter)])
    dop = np.concatenate([dop, c_dop])
    L = np.concatenate([L, np.full(clutter, NOISE, np.int32)])
    # noise growing off boresight
    n = len(r)
    r = r + rng.normal(0, 0.05, n)
    az_n = az + np.radians(rng.normal(0, 1, n) * _sigma(0.3, 2.5, az))
    el_n = el + np.radians(rng.normal(0, 1, n) * _sigma(1.5, 3.5, az))
    dop_n = dop + rng.normal(0, 1, n) * _sigma(0.08, 0.3, az)
    snr = rng.uniform(8, 30, n)
    points = np.column_stack([r * np.cos(el_n) * np.sin(az_n), r * np.cos(el_n) * np.cos(az_n),
                              r * np.sin(el_n), dop_n, snr]).astype(np.float32)
    order = rng.permutation(n)
    points, L = points[order], L[order]

    # camera boxes: every vehicle in view, with box noise and 5-15 % depth error, plus one false box
    cam = make_camera()
    boxes, ids = [], []
    for k in range(V):
        cs = _corners(centres[k], yaws[k], sizes[k][0], sizes[k][1])
        c3 = np.vstack([np.column_stack([cs, np.full(4, -height)]), np.column_stack([cs, np.full(4, 1.5 - height)])])
        pc = c3 @ cam.T_cam_radar[:3, :3].T + cam.T_cam_radar[:3, 3]
        if np.any(pc[:, 2] < 1.0):
            continue
        uv = pc @ cam.K.T
        uv = uv[:, :2] / uv[:, 2:3]
        u1, v1 = uv.min(0) + rng.normal(0, 3, 2)
        u2, v2 = uv.max(0) + rng.normal(0, 3, 2)
        if u2 < 0 or u1 > cam.image_size[0]:
            continue
        ctr = np.append(centres[k], 0.75 - height) @ cam.T_cam_radar[:3, :3].T + cam.T_cam_radar[:3, 3]
        depth = np.hypot(ctr[0], ctr[2]) * (1 + rng.uniform(-0.12, 0.12))
        boxes.append([u1, v1, u2, v2, rng.uniform(0.5, 1.0), depth])
        ids.append(k)
    boxes.append([900, 300, 960, 340, 0.4, 35.0])     # a false detection
    ids.append(-1)
    boxes = np.array(boxes, np.float32).reshape(-1, 6)
    feats = rng.dirichlet(np.ones(16), len(boxes))
    feats = np.hstack([feats, rng.dirichlet(np.ones(8), len(boxes)), rng.dirichlet(np.ones(8), len(boxes))])
    moving_ids = np.array([k for k in range(V) if speeds[k] > 0], np.int32)
    return SynthFrame(points=points, labels=L, moving_ids=moving_ids, boxes=boxes,
                      box_ids=np.array(ids, np.int32), features=feats.astype(np.float32), camera=cam,
                      velocity=v, centres=np.array(centres), radar_height=height)
