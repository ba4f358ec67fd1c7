"""What a TI-like automotive radar reports of a simulated world (one frame).

A vehicle returns a handful of points from the faces turned to the radar, mostly its
corners and whichever face is near-specular; far and oblique vehicles give one or two
points or none. Walls reflect vehicles into mirrored ghosts; clutter adds isolated
false points. Noise in range, azimuth, elevation and Doppler grows off boresight.
Doppler is the true radial velocity of target minus radar (positive = receding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.sim.geometry import box_corners, segments_block
from mmatch.sim.world import FACADE, GUARDRAIL, POLE, VEGETATION, World

LABEL_BACKGROUND = -1
LABEL_NOISE = -2


@dataclass(frozen=True)
class RadarSpec:
    """Field of view, range and error model (TI xWR18xx/AWR2243-class, 3 TX x 4 RX)."""

    fov_az_deg: float = 60.0
    fov_el_deg: float = 20.0
    max_range_m: float = 100.0
    range_sigma_m: float = 0.05
    az_sigma_deg: tuple[float, float] = (0.3, 2.5)      # at boresight, at the FOV edge
    el_sigma_deg: tuple[float, float] = (1.5, 3.5)
    doppler_sigma_mps: tuple[float, float] = (0.05, 0.3)
    ghost_prob: float = 0.12
    clutter_rate: float = 6.0


def _edge_sigma(pair: tuple[float, float], az: np.ndarray, fov: float) -> np.ndarray:
    return pair[0] + (pair[1] - pair[0]) * np.clip(np.abs(az) / np.radians(fov), 0, 1) ** 2


def _vehicle_scatterers(rng, corners, yaw, size, radar_xy):
    """Candidate scattering points (n, 3) and strengths (n,) on the faces turned to the radar."""
    f = np.array([np.cos(yaw), np.sin(yaw)])
    r = np.array([np.sin(yaw), -np.cos(yaw)])
    normals = [f, r, -f, -r]                      # front, right, rear, left
    pts, strength = [], []
    for e in range(4):
        a, b = corners[e], corners[(e + 1) % 4]
        mid = (a + b) / 2
        to_radar = radar_xy - mid
        if normals[e] @ to_radar <= 0:
            continue
        length = float(np.hypot(*(b - a)))
        u = np.concatenate([[0.0, 1.0], np.arange(0.5, length, 0.5) / length])
        p = a + u[:, None] * (b - a)
        ray = radar_xy - p
        cos_inc = np.clip((ray @ normals[e]) / np.linalg.norm(ray, axis=1), 0, 1)
        s = 0.12 + 0.9 * cos_inc ** 8
        s[:2] = 1.0                                   # corners: strong dihedral returns
        pts.append(p)
        strength.append(s)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    p = np.vstack(pts)
    z = rng.uniform(0.25, min(1.1, 0.7 * size[2]), len(p))
    return np.column_stack([p, z]), np.concatenate(strength)


def observe_radar(world: World, t: float, world_T_radar: np.ndarray, radar_velocity: np.ndarray,
                  own: int, rng: np.random.Generator, spec: RadarSpec = RadarSpec()
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Render one radar frame.

    world_T_radar: 4x4 pose of the radar; radar_velocity: (2,) its world velocity, m/s;
    own: index of the carrying vehicle (never seen). Returns points float32 (N, 5)
    x, y, z, doppler, snr in the radar frame and labels int32 (N,) (vehicle id, -1
    background, -2 noise/ghost).
    """
    veh = world.vehicles
    origin = world_T_radar[:2, 3]
    R = world_T_radar[:3, :3]
    centres = veh.position(t)
    corners = box_corners(centres, veh.yaw, veh.size[:, 0], veh.size[:, 1])
    others = np.array([k for k in range(len(veh)) if k != own], int)
    edge_a = corners[others].reshape(-1, 2)
    edge_b = np.roll(corners[others], -1, axis=1).reshape(-1, 2)
    edge_owner = np.repeat(others, 4)
    occ_a = np.vstack([edge_a, world.walls_a[world.wall_occludes]])
    occ_b = np.vstack([edge_b, world.walls_b[world.wall_occludes]])
    occ_owner = np.concatenate([edge_owner, np.full(int(world.wall_occludes.sum()), -9)])

    # ---- stationary structures
    sp = world.static_pts
    rel = sp[:, :2] - origin
    rng_xy = np.hypot(rel[:, 0], rel[:, 1])
    near = rng_xy < spec.max_range_m * 1.05
    sp, kind, rng_xy = sp[near], world.static_kind[near], rng_xy[near]
    p_det = np.select([kind == GUARDRAIL, kind == FACADE, kind == POLE, kind == VEGETATION],
                      [0.9 * np.exp(-rng_xy / 60.0), 0.95 * np.exp(-rng_xy / 90.0),
                       0.95 * np.exp(-rng_xy / 90.0), 0.85 * np.exp(-rng_xy / 70.0)])
    keep = rng.random(len(sp)) < p_det
    sp, kind = sp[keep], kind[keep]
    # points on a facade sit on its line, so their own wall does not hide them (t < 1 in the test)
    blocked = segments_block(origin, sp[:, :2], occ_a, occ_b)
    sp, kind = sp[~blocked], kind[~blocked]
    base_snr = np.select([kind == GUARDRAIL, kind == FACADE, kind == POLE, kind == VEGETATION],
                         [16.0, 20.0, 24.0, 13.0])
    world_pts = [sp]
    world_vel = [np.zeros((len(sp), 2))]
    labels = [np.full(len(sp), LABEL_BACKGROUND)]
    snr0 = [base_snr]

    # ---- vehicles (moving and parked)
    vel = veh.velocity
    ghost_src = []
    for k in others:
        d = float(np.hypot(*(centres[k] - origin)))
        if d > spec.max_range_m or d < 1.0:
            continue
        cand, strength = _vehicle_scatterers(rng, corners[k], veh.yaw[k], veh.size[k], origin)
        if len(cand) == 0:
            continue
        lam = (1.5 + 10.0 * np.exp(-d / 30.0)) * (1.4 if veh.size[k, 0] > 6 else 1.0)
        n = min(int(rng.poisson(lam)), 12, len(cand))
        if rng.random() < 0.08:               # specular dropout: the whole vehicle fades
            n = min(n, int(rng.integers(0, 2)))
        if n == 0:
            continue
        pick = rng.choice(len(cand), size=n, replace=False, p=strength / strength.sum())
        p = cand[pick]
        p[:, :2] += rng.normal(0, 0.08, (n, 2))
        ignore = (occ_owner[None, :] == k).repeat(n, 0)
        vis = ~segments_block(origin, p[:, :2], occ_a, occ_b, ignore)
        p = p[vis]
        if len(p) == 0:
            continue
        world_pts.append(p)
        world_vel.append(np.repeat(vel[k][None], len(p), 0))
        labels.append(np.full(len(p), k))
        snr0.append(np.full(len(p), 30.0 if veh.size[k, 0] > 6 else 27.0))
        ghost_src.append((p, vel[k]))

    # ---- multipath ghosts mirrored across guardrails and facades
    if ghost_src and len(world.walls_a):
        gp, gv = _ghosts(rng, np.vstack([g[0] for g in ghost_src]),
                         np.vstack([np.repeat(g[1][None], len(g[0]), 0) for g in ghost_src]),
                         origin, world.walls_a, world.walls_b, spec.ghost_prob)
        if len(gp):
            world_pts.append(gp)
            world_vel.append(gv)
            labels.append(np.full(len(gp), LABEL_NOISE))
            snr0.append(np.full(len(gp), 18.0))

    P = np.vstack(world_pts)
    V = np.vstack(world_vel)
    lab = np.concatenate(labels).astype(np.int32)
    snr = np.concatenate(snr0)

    # ---- into the radar frame, Doppler, field of view
    local = (P - world_T_radar[:3, 3]) @ R
    rel_v = np.column_stack([V - radar_velocity, np.zeros(len(V))]) @ R
    rng3 = np.linalg.norm(local, axis=1)
    az = np.arctan2(local[:, 0], local[:, 1])
    el = np.arcsin(np.clip(local[:, 2] / np.maximum(rng3, 1e-6), -1, 1))
    doppler = np.einsum("ij,ij->i", rel_v, local) / np.maximum(rng3, 1e-6)
    inside = ((np.abs(az) <= np.radians(spec.fov_az_deg)) & (np.abs(el) <= np.radians(spec.fov_el_deg))
              & (rng3 <= spec.max_range_m) & (rng3 >= 1.0))
    rng3, az, el, doppler, lab, snr = rng3[inside], az[inside], el[inside], doppler[inside], lab[inside], snr[inside]

    # ---- clutter: isolated false detections
    n_cl = int(rng.poisson(spec.clutter_rate))
    if n_cl:
        c_r = rng.uniform(2.0, 80.0, n_cl)
        c_az = rng.uniform(-1, 1, n_cl) * np.radians(spec.fov_az_deg)
        c_el = rng.normal(0, np.radians(4), n_cl)
        vx, vy = np.linalg.inv(R)[:2, :2] @ radar_velocity
        stat = -(vx * np.sin(c_az) + vy * np.cos(c_az)) * np.cos(c_el)
        c_dop = np.where(rng.random(n_cl) < 0.5, stat + rng.normal(0, 1.0, n_cl), rng.uniform(-20, 20, n_cl))
        rng3 = np.concatenate([rng3, c_r])
        az = np.concatenate([az, c_az])
        el = np.concatenate([el, c_el])
        doppler = np.concatenate([doppler, c_dop])
        lab = np.concatenate([lab, np.full(n_cl, LABEL_NOISE, np.int32)])
        snr = np.concatenate([snr, np.full(n_cl, 12.0)])

    # ---- measurement noise growing off boresight
    n = len(rng3)
    r_n = rng3 + rng.normal(0, spec.range_sigma_m + 0.001 * rng3, n)
    az_n = az + np.radians(rng.normal(0, 1, n) * _edge_sigma(spec.az_sigma_deg, az, spec.fov_az_deg))
    el_n = el + np.radians(rng.normal(0, 1, n) * _edge_sigma(spec.el_sigma_deg, az, spec.fov_az_deg))
    dop_n = doppler + rng.normal(0, 1, n) * _edge_sigma(spec.doppler_sigma_mps, az, spec.fov_az_deg)
    snr_n = np.maximum(snr - 30.0 * np.log10(np.maximum(rng3, 1.0) / 10.0) + rng.normal(0, 2.0, n), 5.0)
    pts = np.column_stack([r_n * np.cos(el_n) * np.sin(az_n), r_n * np.cos(el_n) * np.cos(az_n),
                           r_n * np.sin(el_n), dop_n, snr_n]).astype(np.float32)
    order = np.argsort(np.arctan2(pts[:, 0], pts[:, 1]), kind="stable")   # TI lists by range/azimuth bin
    return pts[order], lab[order]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


def _ghosts(rng, pts, vel, origin, wa, wb, prob):
    """Mirror a random subset of vehicle points across the wall whose reflection path is valid."""
    take = rng.random(len(pts)) < prob
    pts, vel = pts[take], vel[take]
    if len(pts) == 0:
        return np.zeros((0, 3)), np.zeros((0, 2))
    d = wb - wa
    n = _unit(np.column_stack([-d[:, 1], d[:, 0]]))                  # (W, 2)
    off_p = np.einsum("wk,nwk->nw", n, pts[:, None, :2] - wa[None])  # signed distance of points
    off_o = np.einsum("wk,wk->w", n, origin[None] - wa)                  # signed distance of radar
    same_side = np.sign(off_p) == np.sign(off_o)[None]
    mirror = pts[:, None, :2] - 2 * off_p[..., None] * n[None]        # (N, W, 2)
    # reflection point: where origin->mirror crosses the wall line; must lie on the segment
    denom = off_o[None] - np.einsum("wk,nwk->nw", n, mirror - wa[None])
    with np.errstate(divide="ignore", invalid="ignore"):
        s = off_o[None] / denom
    hit = origin[None, None] + s[..., None] * (mirror - origin[None, None])
    u = np.einsum("nwk,wk->nw", hit - wa[None], d) / np.einsum("wk,wk->w", d, d)[None]
    valid = same_side & (u >= 0) & (u <= 1) & (s > 0) & (s < 1) & (np.abs(off_p) < 25)
    dist = np.where(valid, np.abs(off_p), np.inf)
    best = np.argmin(dist, axis=1)
    ok = np.isfinite(dist[np.arange(len(pts)), best])
    if not ok.any():
        return np.zeros((0, 3)), np.zeros((0, 2))
    idx = np.flatnonzero(ok)
    w = best[ok]
    gxy = mirror[idx, w]
    nv = n[w]
    gv = vel[idx] - 2 * np.einsum("nk,nk->n", vel[idx], nv)[:, None] * nv
    return np.column_stack([gxy, pts[idx, 2]]), gv
