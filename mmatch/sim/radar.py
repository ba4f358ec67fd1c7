"""What a TI-like automotive radar reports of a simulated world (one frame).

A vehicle returns a handful of points from the faces turned to the radar, mostly its
corners and whichever face is near-specular, plus wheel returns whose Doppler spreads
between standstill and twice the body speed; far and oblique vehicles give one or two
points or none. Walls reflect vehicles into mirrored ghosts; clutter adds isolated false
points. Every return gets an SNR from the radar equation (range^-4 for point-like
scatterers, range^-3 for distributed ones, Swerling-1 fading) conditioned on passing a
soft CFAR threshold, and errors that follow from it: range and Doppler noise grow at low
SNR, azimuth and elevation errors come from the array bound at that SNR and angle, glint
over an extended target's own angular extent and the array's calibration residual
(`mmatch.sim.radar_errors`). The constants no deployment can know come from the scene's
`PhysicsSample` (mmatch/sim/physics.py).
Doppler is the true radial velocity of target minus radar (positive = receding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.sim.geometry import box_corners, segments_block
from mmatch.sim.physics import PhysicsSample, nominal_sample
from mmatch.sim.radar_errors import AngleErrorSpec, draw_angle_errors
from mmatch.sim.world import FACADE, GUARDRAIL, POLE, VEGETATION, World

LABEL_BACKGROUND = -1
LABEL_NOISE = -2


@dataclass(frozen=True)
class RadarSpec:
    """Field of view and range of a TI xWR18xx/AWR2243-class radar (3 TX x 4 RX)."""

    fov_az_deg: float = 60.0
    fov_el_deg: float = 20.0
    max_range_m: float = 100.0


# SNR (dB) of a return 10 m away and the range exponent of its power (4: point-like, 3: distributed)
STATIC_SNR_10M = {GUARDRAIL: (29.0, 3.0), FACADE: (33.0, 3.0), POLE: (38.0, 4.0), VEGETATION: (26.0, 3.0)}
VEHICLE_SNR_10M = 54.0        # a car's strongest corner; trucks +3 dB; weaker faces by their strength
WHEEL_LOSS_DB = 6.0
GHOST_LOSS_DB = 9.0
SNR_REPORT_SIGMA_DB = 1.0     # the radar's own SNR estimate is noisy
SNR_REF_DB = 15.0             # range and Doppler noise are the nominal ones above this SNR
CELL_SHARE = 0.35             # share of a vehicle's angular extent that shares one range-Doppler cell


def snr_mean_db(snr_10m: np.ndarray, exponent: np.ndarray, rng_m: np.ndarray, offset_db: float) -> np.ndarray:
    """Mean SNR (dB) of returns at range rng_m from their SNR at 10 m and the power's range exponent."""
    return snr_10m + offset_db - 10.0 * exponent * np.log10(np.maximum(rng_m, 1.0) / 10.0)


def detected_snr(rng: np.random.Generator, mean_db: np.ndarray, threshold_db: float,
                 retries: int = 4) -> np.ndarray:
    """SNR (dB) of returns that passed a soft CFAR threshold: Swerling-1 fading on the mean,
    drawn again (up to `retries` times) while below threshold + N(0, 1.5) dB."""
    snr = mean_db + 10.0 * np.log10(np.maximum(rng.exponential(1.0, len(mean_db)), 1e-6))
    for _ in range(retries):
        low = snr < threshold_db + rng.normal(0, 1.5, len(snr))
        if not low.any():
            break
        snr[low] = mean_db[low] + 10.0 * np.log10(np.maximum(rng.exponential(1.0, int(low.sum())), 1e-6))
    return np.maximum(snr, threshold_db - 3.0)


def angle_spec(phys: PhysicsSample, rng: np.random.Generator) -> AngleErrorSpec:
    """One radar's angle error constants (mmatch/sim/radar_errors.py) under the scene's physics:
    the array and glint from the sample, the calibration bias drawn for this radar within
    +- calib_bias_*_deg, the per-point floors as given."""
    return AngleErrorSpec(channels_az=int(phys.channels_az), channels_el=int(phys.channels_el),
                          glint_factor=phys.glint_factor,
                          calib_bias_az_deg=float(rng.uniform(-1, 1) * phys.calib_bias_az_deg),
                          calib_bias_el_deg=float(rng.uniform(-1, 1) * phys.calib_bias_el_deg),
                          calib_floor_az_deg=phys.calib_floor_az_deg, calib_floor_el_deg=phys.calib_floor_el_deg)


def _angular_extent(corners: np.ndarray, origin: np.ndarray) -> float:
    """Azimuth extent (rad) of a BEV box (4, 2) seen from origin (2,)."""
    rel = corners - origin
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    ang = np.unwrap(ang - ang[0]) + ang[0]
    return float(np.ptp(ang))


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


def _wheels(rng, centre, yaw, size, n):
    """n wheel-return positions (n, 3) on the wheel arches of one vehicle."""
    f = np.array([np.cos(yaw), np.sin(yaw)])
    r = np.array([np.sin(yaw), -np.cos(yaw)])
    along = rng.choice([-1.0, 1.0], n) * (size[0] / 2 - 0.9)
    side = rng.choice([-1.0, 1.0], n) * size[1] / 2
    xy = centre + along[:, None] * f + side[:, None] * r
    return np.column_stack([xy, rng.uniform(0.2, 0.55, n)])


def observe_radar(world: World, t: float, world_T_radar: np.ndarray, radar_velocity: np.ndarray,
                  own: int, rng: np.random.Generator, spec: RadarSpec = RadarSpec(),
                  phys: PhysicsSample | None = None, array: AngleErrorSpec | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Render one radar frame.

    world_T_radar: 4x4 pose of the radar; radar_velocity: (2,) its world velocity, m/s;
    own: index of the carrying vehicle (never seen); phys: the scene's constants (nominal
    when None); array: this radar's angle error constants (from phys, uncalibrated bias 0,
    when None).
    Returns points float32 (N, 5) x, y, z, doppler, snr in the radar frame and labels int32
    (N,) (vehicle id, -1 background, -2 noise/ghost).
    """
    phys = phys or nominal_sample()
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
    sp, kind, rng_xy = sp[keep], kind[keep], rng_xy[keep]
    # points on a facade sit on its line, so their own wall does not hide them (t < 1 in the test)
    blocked = segments_block(origin, sp[:, :2], occ_a, occ_b)
    sp, kind, rng_xy = sp[~blocked], kind[~blocked], rng_xy[~blocked]
    s10 = np.zeros(len(kind))
    expo = np.zeros(len(kind))
    for k, (s, e) in STATIC_SNR_10M.items():
        s10[kind == k], expo[kind == k] = s, e
    world_pts = [sp]
    world_vel = [np.zeros((len(sp), 2))]
    labels = [np.full(len(sp), LABEL_BACKGROUND)]
    snr_mean = [snr_mean_db(s10, expo, rng_xy, phys.snr_offset_db)]
    # the part of a structure sharing one range-Doppler cell: a bush or a stretch of facade
    # spans some of a degree, a pole or a guardrail post hardly any (angle glint, radar_errors.py)
    size = np.select([kind == VEGETATION, kind == FACADE, kind == GUARDRAIL], [rng.uniform(0.5, 3.0, len(kind)),
                     rng.uniform(0.3, 1.5, len(kind)), np.full(len(kind), 0.3)], 0.0)
    extent = [size / np.maximum(rng_xy, 1.0)]

    # ---- vehicles (moving and parked)
    vel = veh.velocity
    ghost_src = []
    for k in others:
        d = float(np.hypot(*(centres[k] - origin)))
        if d > spec.max_range_m or d < 1.0:
            continue
        # scattering centres sit inside the bounding box: bumpers and corners are rounded
        inset = rng.uniform(0.15, 0.35, 2)
        inner = box_corners(centres[k][None], veh.yaw[k:k + 1], veh.size[k:k + 1, 0] - 2 * inset[0],
                            veh.size[k:k + 1, 1] - 2 * inset[1])[0]
        cand, strength = _vehicle_scatterers(rng, inner, veh.yaw[k], veh.size[k], origin)
        if len(cand) == 0:
            continue
        lam = (1.5 + 10.0 * np.exp(-d / 30.0)) * (1.4 if veh.size[k, 0] > 6 else 1.0) * phys.points_scale
        n = min(int(rng.poisson(lam)), 12, len(cand))
        if rng.random() < 0.08:               # specular dropout: the whole vehicle fades
            n = min(n, int(rng.integers(0, 2)))
        if n == 0:
            continue
        pick = rng.choice(len(cand), size=n, replace=False, p=strength / strength.sum())
        p = cand[pick]
        p[:, :2] += rng.normal(0, 0.08, (n, 2))
        s_db = VEHICLE_SNR_10M + 10.0 * np.log10(strength[pick]) + (3.0 if veh.size[k, 0] > 6 else 0.0)
        v_pts = np.repeat(vel[k][None], n, 0)
        if veh.speed[k] > 0.5:                # wheel returns: surface speed 0 ... 2 x body speed
            wheel = rng.random(n) < phys.wheel_share
            if wheel.any():
                p[wheel] = _wheels(rng, centres[k], veh.yaw[k], veh.size[k], int(wheel.sum()))
                v_pts[wheel] = vel[k] * rng.uniform(0.0, 2.0, (int(wheel.sum()), 1))
                s_db[wheel] = VEHICLE_SNR_10M - WHEEL_LOSS_DB
        ignore = (occ_owner[None, :] == k).repeat(n, 0)
        vis = ~segments_block(origin, p[:, :2], occ_a, occ_b, ignore)
        p, v_pts, s_db = p[vis], v_pts[vis], s_db[vis]
        if len(p) == 0:
            continue
        ext = _angular_extent(corners[k], origin)
        world_pts.append(p)
        world_vel.append(v_pts)
        labels.append(np.full(len(p), k))
        snr_mean.append(snr_mean_db(s_db, np.full(len(p), 4.0), np.full(len(p), d), phys.snr_offset_db))
        extent.append(np.full(len(p), CELL_SHARE * ext))
        ghost_src.append((p, v_pts, snr_mean[-1], ext))

    # ---- multipath ghosts mirrored across guardrails and facades
    if ghost_src and len(world.walls_a):
        gp, gv, take = _ghosts(rng, np.vstack([g[0] for g in ghost_src]), np.vstack([g[1] for g in ghost_src]),
                               origin, world.walls_a, world.walls_b, phys.ghost_prob)
        if len(gp):
            world_pts.append(gp)
            world_vel.append(gv)
            labels.append(np.full(len(gp), LABEL_NOISE))
            snr_mean.append(np.concatenate([g[2] for g in ghost_src])[take] - GHOST_LOSS_DB)
            extent.append(np.concatenate([np.full(len(g[0]), g[3]) for g in ghost_src])[take])

    P = np.vstack(world_pts)
    V = np.vstack(world_vel)
    lab = np.concatenate(labels).astype(np.int32)
    mean_db = np.concatenate(snr_mean)
    ext = np.concatenate(extent)

    # ---- into the radar frame, Doppler, field of view
    local = (P - world_T_radar[:3, 3]) @ R
    rel_v = np.column_stack([V - radar_velocity, np.zeros(len(V))]) @ R
    rng3 = np.linalg.norm(local, axis=1)
    az = np.arctan2(local[:, 0], local[:, 1])
    el = np.arcsin(np.clip(local[:, 2] / np.maximum(rng3, 1e-6), -1, 1))
    doppler = np.einsum("ij,ij->i", rel_v, local) / np.maximum(rng3, 1e-6)
    inside = ((np.abs(az) <= np.radians(spec.fov_az_deg)) & (np.abs(el) <= np.radians(spec.fov_el_deg))
              & (rng3 <= spec.max_range_m) & (rng3 >= 1.0))
    rng3, az, el, doppler, lab, mean_db, ext = (a[inside] for a in (rng3, az, el, doppler, lab, mean_db, ext))

    # ---- clutter: isolated false detections, near the detection threshold
    n_cl = int(rng.poisson(phys.clutter_rate))
    if n_cl:
        c_r = rng.uniform(2.0, 80.0, n_cl)
        c_az = rng.uniform(-1, 1, n_cl) * np.radians(spec.fov_az_deg)
        c_el = rng.normal(0, np.radians(4), n_cl)
        vx, vy = np.linalg.inv(R)[:2, :2] @ radar_velocity
        stat = -(vx * np.sin(c_az) + vy * np.cos(c_az)) * np.cos(c_el)
        c_dop = np.where(rng.random(n_cl) < 0.5, stat + rng.normal(0, 1.0, n_cl), rng.uniform(-20, 20, n_cl))
        rng3, az, el, doppler = (np.concatenate(x) for x in ((rng3, c_r), (az, c_az), (el, c_el), (doppler, c_dop)))
        lab = np.concatenate([lab, np.full(n_cl, LABEL_NOISE, np.int32)])
        mean_db = np.concatenate([mean_db, phys.detection_threshold_db + rng.exponential(3.0, n_cl)])
        ext = np.concatenate([ext, np.zeros(n_cl)])

    # ---- SNR, then errors that follow from it
    n = len(rng3)
    snr = detected_snr(rng, mean_db, phys.detection_threshold_db)
    weak = np.maximum(1.0, 10.0 ** ((SNR_REF_DB - snr) / 20.0))           # amplitude ratio below the reference
    r_n = rng3 + rng.normal(0, 1, n) * (phys.range_sigma_m * weak + 0.001 * rng3)
    dop_n = doppler + rng.normal(0, 1, n) * phys.doppler_sigma_mps * weak
    spec = array or angle_spec(phys, np.random.default_rng(0))
    d_az, d_el = draw_angle_errors(rng, snr, az, el, ext, 0.5 * ext, spec)
    az_n, el_n = az + phys.angle_noise_scale * d_az, el + phys.angle_noise_scale * d_el
    snr_rep = np.maximum(snr + rng.normal(0, SNR_REPORT_SIGMA_DB, n), 0.0)
    pts = np.column_stack([r_n * np.cos(el_n) * np.sin(az_n), r_n * np.cos(el_n) * np.cos(az_n),
                           r_n * np.sin(el_n), dop_n, snr_rep]).astype(np.float32)
    order = np.argsort(np.arctan2(pts[:, 0], pts[:, 1]), kind="stable")   # TI lists by range/azimuth bin
    return pts[order], lab[order]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


def _ghosts(rng, pts, vel, origin, wa, wb, prob):
    """Mirror a random subset of vehicle points across the wall whose reflection path is valid.

    Returns ghost positions (G, 3), velocities (G, 2) and the index of each one's source point.
    """
    src = np.flatnonzero(rng.random(len(pts)) < prob)
    none = (np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, int))
    pts, vel = pts[src], vel[src]
    if len(pts) == 0:
        return none
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
        return none
    idx = np.flatnonzero(ok)
    w = best[ok]
    gxy = mirror[idx, w]
    nv = n[w]
    gv = vel[idx] - 2 * np.einsum("nk,nk->n", vel[idx], nv)[:, None] * nv
    return np.column_stack([gxy, pts[idx, 2]]), gv, src[idx]
