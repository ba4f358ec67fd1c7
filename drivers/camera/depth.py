"""Monocular depth per box: from the model when it has a depth output, else from the ground plane.

Ground-plane geometry (camera frame: OpenCV, x right, y down, z forward; metres):
the ray through the bottom-centre pixel of a box meets the road (a plane `h` metres below
the camera, normal `up`) at the vehicle's contact point s * r with s = -h / (up . r). The
vehicle centre is taken `center_offset` metres further along the horizontal viewing
direction and `vehicle_height / 2` above the road; the depth is the camera-to-centre
distance (the `depth` column of a box, DESIGN.md).

The uncertainty (1 sigma, metres) combines, in quadrature, the effect of `sigma_px` pixels of
bottom-edge error and `sigma_pitch_deg` of pitch error (finite differences) and
`sigma_offset` for the unknown vehicle extent. Where the ray does not meet the road within
`max_range` (bottom edge at or above the horizon) the size prior is used instead:
depth = fy * vehicle_height / box height, sigma = `size_prior_rel_sigma` x depth.
A box whose bottom edge touches the image border (vehicle cut off) gets twice the sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GroundPlane:
    """The road seen from the camera: camera height above it (m), pitch (deg, positive = optical
    axis looking down) and roll (deg, rotation about the optical axis; `up` in the camera frame
    is Rz(roll) @ (0, -cos pitch, -sin pitch))."""

    camera_height: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    def up(self) -> np.ndarray:
        """World 'up' expressed in the camera frame (unit 3-vector)."""
        p, r = np.deg2rad(self.pitch_deg), np.deg2rad(self.roll_deg)
        # level camera: up = -y. Pitch down by p: the forward axis gains a downward component.
        up = np.array([0.0, -np.cos(p), -np.sin(p)])
        # roll about the optical axis
        c, s = np.cos(r), np.sin(r)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return Rz @ up

    @classmethod
    def from_extrinsic(cls, T_cam_radar: np.ndarray, radar_height: float) -> GroundPlane:
        """Ground plane from the radar->camera extrinsic and the radar's height above the road
        (radar frame: z up, so the road is z = -radar_height there)."""
        T = np.asarray(T_cam_radar, np.float64)
        R, t = T[:3, :3], T[:3, 3]
        up = R[:, 2]  # radar +z in camera coordinates
        cam_in_radar = -R.T @ t
        height = radar_height + cam_in_radar[2]
        pitch = np.rad2deg(np.arcsin(np.clip(-up[2], -1, 1)))
        roll = np.rad2deg(np.arctan2(up[0], -up[1]))  # up = (sin r cos p, -cos r cos p, -sin p)
        return cls(float(height), float(pitch), float(roll))


@dataclass(frozen=True)
class DepthConfig:
    """Ground-plane depth settings (metres, pixels, degrees)."""

    center_offset: float = 1.5
    vehicle_height: float = 1.5
    sigma_px: float = 2.0
    sigma_pitch_deg: float = 1.0
    sigma_offset: float = 1.0
    max_range: float = 150.0
    size_prior_rel_sigma: float = 0.3
    model_rel_sigma: float = 0.1


def _centre_distance(
    u: np.ndarray, v: np.ndarray, Kinv: np.ndarray, up: np.ndarray, h: float, cfg: DepthConfig
) -> np.ndarray:
    """Camera-to-vehicle-centre distance for bottom-centre pixels (u, v); NaN where the ray
    misses the road within max_range."""
    rays = np.stack([u, v, np.ones_like(u)], axis=1) @ Kinv.T  # (M, 3)
    denom = rays @ up
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom < -1e-9, -h / denom, np.nan)
    contact = rays * s[:, None]
    horiz = contact - np.outer(contact @ up, up)  # component in the road plane
    norm = np.linalg.norm(horiz, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        centre = contact + horiz / norm * cfg.center_offset + up * (cfg.vehicle_height / 2)
    d = np.linalg.norm(centre, axis=1)
    return np.where(np.linalg.norm(contact, axis=1) <= cfg.max_range, d, np.nan)


def ground_plane_depth(
    boxes: np.ndarray,
    K: np.ndarray,
    ground: GroundPlane,
    image_size: tuple[int, int] | None = None,
    config: DepthConfig | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth (m, camera to vehicle centre) and its 1-sigma uncertainty (m) per box.

    boxes: (M, >=4) u1, v1, u2, v2 in *undistorted* pixels; K: (3, 3) intrinsics;
    image_size: (width, height) to detect boxes cut off at the bottom border.
    Returns two float32 (M,) arrays.
    """
    cfg = config or DepthConfig()
    b = np.asarray(boxes, np.float64)
    if b.size == 0:
        return np.zeros(0, np.float32), np.zeros(0, np.float32)
    K = np.asarray(K, np.float64)
    Kinv = np.linalg.inv(K)
    u = (b[:, 0] + b[:, 2]) / 2
    v = b[:, 3]
    up = ground.up()
    h = ground.camera_height
    d = _centre_distance(u, v, Kinv, up, h, cfg)
    d_v = _centre_distance(u, v + cfg.sigma_px, Kinv, up, h, cfg)
    tilted = GroundPlane(h, ground.pitch_deg + cfg.sigma_pitch_deg, ground.roll_deg).up()
    d_p = _centre_distance(u, v, Kinv, tilted, h, cfg)
    sigma = np.sqrt(np.nan_to_num(d_v - d) ** 2 + np.nan_to_num(d_p - d) ** 2 + cfg.sigma_offset**2)
    # Size prior where the ground plane gives nothing usable.
    box_h = np.maximum(b[:, 3] - b[:, 1], 1.0)
    prior = K[1, 1] * cfg.vehicle_height / box_h
    bad = ~np.isfinite(d) | ~np.isfinite(d_v) | ~np.isfinite(d_p)
    d = np.where(bad, prior, d)
    sigma = np.where(bad, cfg.size_prior_rel_sigma * prior, sigma)
    if image_size is not None:
        cut = b[:, 3] >= image_size[1] - 1
        sigma = np.where(cut, 2 * sigma, sigma)
    return d.astype(np.float32), sigma.astype(np.float32)


def model_depth_sigma(depth: np.ndarray, config: DepthConfig | None = None) -> np.ndarray:
    """1-sigma uncertainty (m) assigned to a depth the model predicted: a fixed fraction of it."""
    cfg = config or DepthConfig()
    return (np.abs(np.asarray(depth, np.float32)) * np.float32(cfg.model_rel_sigma)).astype(
        np.float32
    )
