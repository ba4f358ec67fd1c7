"""Frustum separation: which radar points belong to which camera detection (the paper's step 2).

For every box: the points that project into the box (through T_cam_radar and K) within a
depth window `depth +- (delta_d + depth_rel * depth)` around the box's monocular depth, and
the moving points in the box's bearing wedge (BEV) within the wider window
`depth +- (delta_d + moving_depth_rel * depth)`. A point claimed
by several boxes goes to the one whose depth is nearest its own range. Ranges and depths
are horizontal (BEV) distances from the camera centre, metres: the box depth is read as the
camera-to-vehicle-centre distance a monocular 3D detector reports.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.cav.config import SeparationConfig
from mmatch.types import CameraModel


@dataclass
class Projection:
    """Radar points seen by the camera.

    uv: float64 (N, 2) pixel coordinates (NaN behind the camera); front: bool (N,) in front
    of the camera by at least min_camera_z_m; bev_range: float64 (N,) horizontal distance
    from the camera centre, m (sqrt(x_cam^2 + z_cam^2)).
    """

    uv: np.ndarray
    front: np.ndarray
    bev_range: np.ndarray


@dataclass
class Separation:
    """Assignment of the N points of a frame to the M boxes.

    owner: int32 (N,) box index claiming each point, -1 for none.
    claimed_moving: int32 (M,) moving points each box owns; claimed: int32 (M,) all points it owns.
    active: bool (M,) boxes taken into account (score >= min_box_score).
    """

    owner: np.ndarray
    claimed: np.ndarray
    claimed_moving: np.ndarray
    active: np.ndarray


def project(xyz: np.ndarray, camera: CameraModel, min_z: float = 0.5) -> Projection:
    """Project radar-frame points (N, 3) m into the image of `camera`."""
    T = np.asarray(camera.T_cam_radar, np.float64)
    pc = np.asarray(xyz, np.float64) @ T[:3, :3].T + T[:3, 3]
    front = pc[:, 2] > min_z
    uvw = pc @ np.asarray(camera.K, np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / np.where(front, uvw[:, 2], np.nan)[:, None]
    return Projection(uv=uv, front=front, bev_range=np.hypot(pc[:, 0], pc[:, 2]))


def box_rays(boxes: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre (3,) and unit BEV directions (M, 3) through the box centres, radar frame.

    The direction is the ray through the box's centre pixel, flattened to the camera's
    horizontal plane (x_cam, z_cam) and expressed in radar coordinates.
    """
    K = np.asarray(camera.K, np.float64)
    T = np.asarray(camera.T_cam_radar, np.float64)
    uc = (boxes[:, 0] + boxes[:, 2]) / 2.0
    vc = (boxes[:, 1] + boxes[:, 3]) / 2.0
    rays = np.column_stack([uc, vc, np.ones(len(boxes))]) @ np.linalg.inv(K).T
    rays[:, 1] = 0.0                                        # horizontal plane of the camera
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    R = T[:3, :3]
    origin = -R.T @ T[:3, 3]                                # camera centre in the radar frame
    return origin, rays @ R                                 # R^T applied to each row


def centres_from_boxes(boxes: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Vehicle centres (M, 2) x, y in the radar frame from each box's bearing and depth, m."""
    if len(boxes) == 0:
        return np.zeros((0, 2))
    origin, dirs = box_rays(np.asarray(boxes, np.float64), camera)
    return (origin[None, :] + dirs * np.asarray(boxes[:, 5], np.float64)[:, None])[:, :2]


def separate(points: np.ndarray, moving: np.ndarray, boxes: np.ndarray, camera: CameraModel,
             config: SeparationConfig | None = None, proj: Projection | None = None,
             residual: np.ndarray | None = None, sigma_az: np.ndarray | None = None,
             sigma_doppler: np.ndarray | None = None) -> Separation:
    """Assign points (N, >=3, radar frame) to boxes (M, 6) u1, v1, u2, v2, score, depth.

    moving: bool (N,) from the ego-motion fit. A box claims a point when
    - the point projects into the box (grown by box_margin_px, and vertically by
      elevation_margin_deg for the radar's poor elevation) and its BEV range is within
      depth +- (delta_d + depth_rel * depth), or
    - the point moves, lies in the box's bearing wedge (u1 <= u <= u2, grown by
      bearing_margin_deg, or by bearing_margin_sigma standard deviations of the point's
      own azimuth error when sigma_az (N,) rad is given, plus glint over the box's width)
      and within depth +- (delta_d + moving_depth_rel * depth).
    A box touching the image's left or right edge (edge_px) is open to that side.

    One point, one box. Without Doppler information (residual None) the box whose depth
    is nearest the point's range wins. With residual (N,) m/s (Doppler minus the
    stationary prediction) and sigma_doppler (N,) m/s, a point claimed by several boxes
    goes to the one its depth and Doppler agree with: cost = (range gap / depth window)^2
    + (residual - the box's own radial motion)^2 / sigma^2, the box's motion being the
    median residual of the points only it claims (0 for a box of stationary points).
    Vectorised over the (N, M) point-box pairs.
    """
    cfg = config or SeparationConfig()
    n, m = len(points), len(boxes)
    if n == 0 or m == 0:
        return Separation(owner=np.full(n, -1, np.int32), claimed=np.zeros(m, np.int32),
                          claimed_moving=np.zeros(m, np.int32),
                          active=np.asarray(boxes[:, 4] >= cfg.min_box_score, bool) if m else np.zeros(0, bool))
    pr = proj or project(points[:, :3], camera, cfg.min_camera_z_m)
    b = np.asarray(boxes, np.float64)
    active = b[:, 4] >= cfg.min_box_score
    mg = cfg.box_margin_px
    # wedge margin: the radar's azimuth noise grows off boresight; in pixels at the box's column
    fx, cx = float(camera.K[0, 0]), float(camera.K[0, 2])
    az_box = np.arctan(np.abs((b[:, 0] + b[:, 2]) / 2 - cx) / fx)
    px_per_rad = fx / np.cos(az_box) ** 2                                  # (M,)
    if sigma_az is not None and cfg.bearing_margin_sigma > 0:
        width_rad = (b[:, 2] - b[:, 0]) / px_per_rad
        ang = np.hypot(np.asarray(sigma_az, np.float64)[:, None], cfg.glint_share * width_rad[None, :])
        mu = mg + cfg.bearing_margin_sigma * ang * px_per_rad[None, :]       # (N, M)
    else:
        margin = np.radians(cfg.bearing_margin_deg
                            + cfg.bearing_margin_growth_deg * np.clip(az_box / np.radians(60.0), 0, 1) ** 2)
        mu = (mg + px_per_rad * margin)[None, :]
    # a box within edge_px of the image's left or right edge is cut by it: open that side
    left = b[:, 0] <= cfg.edge_px
    right = b[:, 2] >= camera.image_size[0] - 1 - cfg.edge_px
    lo, hi = np.where(left[None], -np.inf, b[None, :, 0] - mu), np.where(right[None], np.inf, b[None, :, 2] + mu)
    lo_box, hi_box = np.where(left, -np.inf, b[:, 0] - mg), np.where(right, np.inf, b[:, 2] + mg)
    mv = mg + float(camera.K[1, 1]) * np.tan(np.radians(min(cfg.elevation_margin_deg, 89.0)))
    u, v = pr.uv[:, 0:1], pr.uv[:, 1:2]
    with np.errstate(invalid="ignore"):
        wedge = pr.front[:, None] & (u >= lo) & (u <= hi)
        in_box = pr.front[:, None] & (u >= lo_box[None, :]) & (u <= hi_box[None, :]) \
            & (v >= b[None, :, 1] - mv) & (v <= b[None, :, 3] + mv)
    gap = np.abs(pr.bev_range[:, None] - b[None, :, 5])                 # (N, M)
    window = cfg.delta_d_m + cfg.depth_rel * b[None, :, 5]
    window_moving = cfg.delta_d_m + cfg.moving_depth_rel * b[None, :, 5]
    mov = np.asarray(moving, bool)[:, None]
    claim_box = in_box & (gap <= window)
    claim_wedge = wedge & mov & (gap <= window_moving)
    claim = (claim_box | claim_wedge) & active[None, :]
    cost = np.where(claim, gap, np.inf)
    if residual is not None and sigma_doppler is not None:
        cost = _doppler_cost(claim, gap, np.where(claim_box, window, window_moving), mov[:, 0],
                             np.asarray(residual, np.float64), np.asarray(sigma_doppler, np.float64))
    best = np.argmin(cost, axis=1)
    owner = np.where(np.isfinite(cost[np.arange(n), best]), best, -1).astype(np.int32)
    mine = owner >= 0
    claimed = np.bincount(owner[mine], minlength=m).astype(np.int32)
    claimed_moving = np.bincount(owner[mine & moving], minlength=m).astype(np.int32)
    return Separation(owner=owner, claimed=claimed, claimed_moving=claimed_moving, active=active)


def _doppler_cost(claim: np.ndarray, gap: np.ndarray, window: np.ndarray, moving: np.ndarray,
                  residual: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(N, M) cost of giving each point to each claiming box: depth gap and Doppler disagreement.

    A box's own radial motion is the median residual of its moving points among those only
    it claims, when those outnumber its stationary ones; otherwise it is a box of stationary
    points (motion 0).
    """
    n, m = claim.shape
    sole = claim.sum(axis=1) == 1
    col = np.argmax(claim, axis=1)
    motion = np.zeros(m)
    for k in range(m):
        own = sole & (col == k)
        mv = own & moving
        if mv.sum() >= max(1, (own & ~moving).sum()):
            motion[k] = float(np.median(residual[mv]))
    s = np.maximum(sigma, 1e-3)[:, None]
    cost = (gap / np.maximum(window, 1e-6)) ** 2 + ((residual[:, None] - motion[None, :]) / s) ** 2
    return np.where(claim, cost, np.inf)


def grow(points: np.ndarray, residual: np.ndarray, moving: np.ndarray, owner: np.ndarray, boxes: np.ndarray,
         camera: CameraModel, proj: Projection, config: SeparationConfig | None = None) -> np.ndarray:
    """Owner (N,) with unclaimed moving points adopted by the box whose moving points they touch.

    Radar azimuth noise (0.3-2.5 deg, worst off boresight) puts some returns of a vehicle
    just outside its box's wedge. An unclaimed moving point joins box b when it lies within
    grow_eps_m of one of b's moving points in (x, y, velocity_scale * residual), its
    column is within grow_margin_deg of the box, and its range is inside the box's moving
    depth window. Claimed points never change hands.
    """
    cfg = config or SeparationConfig()
    owner = owner.copy()
    if cfg.grow_eps_m <= 0 or len(boxes) == 0:
        return owner
    seeds = np.flatnonzero((owner >= 0) & moving)
    cand = np.flatnonzero((owner < 0) & moving & proj.front)
    if len(seeds) == 0 or len(cand) == 0:
        return owner
    feat = np.column_stack([points[:, 0], points[:, 1], cfg.grow_velocity_scale_s * residual])
    d = np.linalg.norm(feat[cand, None] - feat[None, seeds], axis=2)          # (C, S)
    j = d.argmin(axis=1)
    b = owner[seeds[j]]
    bx = np.asarray(boxes, np.float64)[b]
    fx = float(camera.K[0, 0])
    u = proj.uv[cand, 0]
    off = np.maximum(np.maximum(bx[:, 0] - u, u - bx[:, 2]), 0.0)
    ok = (d[np.arange(len(cand)), j] <= cfg.grow_eps_m) \
        & (off <= fx * np.tan(np.radians(cfg.grow_margin_deg))) \
        & (np.abs(proj.bev_range[cand] - bx[:, 5]) <= cfg.delta_d_m + cfg.moving_depth_rel * bx[:, 5])
    owner[cand[ok]] = b[ok]
    return owner
