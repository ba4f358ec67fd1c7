"""What a monocular camera with a 3-D vehicle detector reports of a simulated world.

Boxes are the pinhole projection of each vehicle's 3-D box, clipped to the image, with
pixel noise, misses (more when occluded or far) and false detections; depth is the
camera-to-vehicle-centre distance with a 5-18 % relative error, as monocular 3-D
detectors give. False detections are of three kinds, as real detectors make them: a
second box on part of a real vehicle (its radar points move), a box on roadside
structure (a sign, a bush, a pole: stationary radar points), and boxes on nothing.
Detection scores pass through the detector's own calibration (a slope and bias on the
logit). The constants come from the scene's `PhysicsSample`. Appearance descriptors are synthesised as the HSV histogram
(DESIGN.md: 16 hue + 8 saturation + 8 value bins, OpenCV ranges) of pixels drawn from
the body colour under this view's lighting, glass, tyres and shadow, and background:
two white cars are as alike to the descriptor as they are to a real camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.sim.geometry import box_corners, segments_block
from mmatch.sim.physics import PhysicsSample, nominal_sample
from mmatch.sim.world import FACADE, POLE, VEGETATION, World

# body colours as (hue 0-180, saturation 0-255, value 0-255) centres and spreads
PALETTE = np.array([
    [0, 12, 225],     # white
    [105, 18, 175],   # silver
    [105, 20, 120],   # grey
    [0, 25, 35],      # black
    [112, 170, 120],  # blue
    [2, 200, 150],    # red
    [70, 120, 70],    # dark green
    [25, 190, 200],   # yellow / orange
], float)
ACHROMATIC = np.array([True, True, True, True, False, False, False, False])
PIXELS_PER_BOX = 256


@dataclass(frozen=True)
class CameraSpec:
    """Image size and the detector's reach (its error model is in PhysicsSample)."""

    width: int = 1280
    height: int = 720
    box_sigma_rel: float = 0.03
    max_range_m: float = 90.0


@dataclass(frozen=True)
class CameraResponse:
    """How one camera renders colour: exposure gain, hue shift (OpenCV units), saturation gain,
    and the pixels a box gives its descriptor."""

    gain: float = 1.0
    hue_shift: float = 0.0
    saturation_gain: float = 1.0
    pixels: int = PIXELS_PER_BOX


def calibrate_score(score: np.ndarray, slope: float, bias: float) -> np.ndarray:
    """A detector's reported score: its calibration applied on the logit of the true confidence."""
    p = np.clip(np.asarray(score, float), 1e-4, 1 - 1e-4)
    z = slope * np.log(p / (1 - p)) + bias
    return 1.0 / (1.0 + np.exp(-z))


def opencv_from_sensor() -> np.ndarray:
    """Rotation taking sensor axes (x right, y forward, z up) to OpenCV camera axes (x right, y down, z forward)."""
    return np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


def camera_pose_from(world_T_cam_sensor: np.ndarray, pitch_rad: float) -> np.ndarray:
    """world_T_cam (OpenCV axes) from a forward-looking sensor pose and a downward pitch."""
    c, s = np.cos(pitch_rad), np.sin(pitch_rad)
    pitch = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])   # about camera x; positive looks down
    T = np.eye(4)
    T[:3, :3] = world_T_cam_sensor[:3, :3] @ opencv_from_sensor().T @ pitch.T
    T[:3, 3] = world_T_cam_sensor[:3, 3]
    return T


def histogram_descriptor(hsv: np.ndarray) -> np.ndarray:
    """(M, P, 3) HSV pixels (OpenCV ranges) -> (M, 32) float32 descriptor, each group sums to 1."""
    h = np.clip((hsv[..., 0] / 180.0 * 16).astype(int), 0, 15)
    s = np.clip((hsv[..., 1] / 256.0 * 8).astype(int), 0, 7)
    v = np.clip((hsv[..., 2] / 256.0 * 8).astype(int), 0, 7)
    m, p = hsv.shape[:2]
    rows = np.repeat(np.arange(m), p)
    out = np.zeros((m, 32), np.float32)
    np.add.at(out, (rows, h.ravel()), 1.0)
    np.add.at(out, (rows, 16 + s.ravel()), 1.0)
    np.add.at(out, (rows, 24 + v.ravel()), 1.0)
    out /= p
    return out


def synth_descriptors(rng: np.random.Generator, colours: np.ndarray, response: CameraResponse | float,
                      occlusion: np.ndarray) -> np.ndarray:
    """Descriptors (M, 32) for vehicles of palette `colours` (M,) seen by a camera of `response`
    (a bare number is an exposure gain).

    occlusion (M,) in 0-1 raises the share of foreign pixels in the box.
    """
    if not isinstance(response, CameraResponse):
        response = CameraResponse(gain=float(response))
    gain = response.gain
    m = len(colours)
    if m == 0:
        return np.zeros((0, 32), np.float32)
    P = max(int(response.pixels), 8)
    base = PALETTE[colours]
    body_frac = np.clip(rng.uniform(0.4, 0.65, m) * (1 - 0.6 * occlusion), 0.1, 1)
    glass_frac = rng.uniform(0.1, 0.22, m)
    dark_frac = rng.uniform(0.05, 0.15, m)
    u = rng.random((m, P))
    c1 = body_frac[:, None]
    c2 = c1 + glass_frac[:, None]
    c3 = c2 + dark_frac[:, None]
    hsv = np.empty((m, P, 3))
    # body: the colour under this view's light, with shading across the faces
    ach = ACHROMATIC[colours][:, None]
    body_h = np.where(ach, rng.uniform(0, 180, (m, P)), (base[:, None, 0] + rng.normal(0, 4, (m, P))) % 180)
    body_s = np.clip(base[:, None, 1] * rng.uniform(0.7, 1.2, (m, 1)) + rng.normal(0, 12, (m, P)), 0, 255)
    body_v = np.clip(base[:, None, 2] * gain * rng.uniform(0.8, 1.15, (m, 1)) + rng.normal(0, 22, (m, P)), 0, 255)
    glass = (rng.uniform(0, 180, (m, P)), rng.uniform(0, 60, (m, P)), rng.uniform(20, 140, (m, P)) * gain)
    dark = (rng.uniform(0, 180, (m, P)), rng.uniform(0, 50, (m, P)), rng.uniform(5, 45, (m, P)))
    bg_kind = rng.random((m, 1))
    bg = (np.where(bg_kind < 0.6, rng.uniform(0, 180, (m, P)), rng.normal(35, 10, (m, P)) % 180),
          np.where(bg_kind < 0.6, rng.uniform(0, 35, (m, P)), rng.uniform(40, 140, (m, P))),
          np.clip(rng.normal(120, 30, (m, P)) * gain, 0, 255))
    for ch, (b, g, d, k) in enumerate(zip((body_h, body_s, body_v), glass, dark, bg)):
        hsv[..., ch] = np.where(u < c1, b, np.where(u < c2, g, np.where(u < c3, d, k)))
    hsv[..., 0] = (hsv[..., 0] + response.hue_shift) % 180
    hsv[..., 1] = np.clip(hsv[..., 1] * response.saturation_gain, 0, 255)
    return histogram_descriptor(hsv)


def observe_camera(world: World, t: float, world_T_cam: np.ndarray, K: np.ndarray, own: int,
                   rng: np.random.Generator, spec: CameraSpec, depth_sigma_rel: float,
                   response: CameraResponse | float, phys: PhysicsSample | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render detections: boxes float32 (M, 6), descriptors float32 (M, 32), vehicle ids int32 (M,).

    world_T_cam: the camera's true pose (OpenCV axes); phys: the scene's detector constants
    (nominal when None). False detections have id -1.
    """
    phys = phys or nominal_sample()
    veh = world.vehicles
    centres = veh.position(t)
    corners2 = box_corners(centres, veh.yaw, veh.size[:, 0], veh.size[:, 1])
    cam_T_world = np.linalg.inv(world_T_cam)
    cam_xy = world_T_cam[:2, 3]
    others = [k for k in range(len(veh)) if k != own]
    occ_edges_a = np.vstack([corners2[[k for k in others]].reshape(-1, 2), world.walls_a[world.wall_occludes]])
    occ_edges_b = np.vstack([np.roll(corners2[others], -1, axis=1).reshape(-1, 2),
                             world.walls_b[world.wall_occludes]])
    owner = np.concatenate([np.repeat(others, 4), np.full(int(world.wall_occludes.sum()), -9)])
    boxes, ids, occl = [], [], []
    for k in others:
        c3 = np.array([centres[k, 0], centres[k, 1], veh.size[k, 2] / 2])
        cc = cam_T_world[:3, :3] @ c3 + cam_T_world[:3, 3]
        dist = float(np.linalg.norm(cc))
        if cc[2] < 2.0 or dist > spec.max_range_m:
            continue
        z = np.array([0.0, veh.size[k, 2]])
        pts = np.array([[*xy, zz] for xy in corners2[k] for zz in z])
        pc = pts @ cam_T_world[:3, :3].T + cam_T_world[:3, 3]
        if np.any(pc[:, 2] < 0.3):
            continue
        uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
        u1, v1 = uv.min(0)
        u2, v2 = uv.max(0)
        full = (u2 - u1) * (v2 - v1)
        cu1, cv1 = max(u1, 0), max(v1, 0)
        cu2, cv2 = min(u2, spec.width - 1), min(v2, spec.height - 1)
        if cu2 - cu1 < 8 or cv2 - cv1 < 8 or (cu2 - cu1) * (cv2 - cv1) < 0.4 * full:
            continue
        # occlusion: rays to the outline and centre, blocked by other vehicles or facades
        samples = np.vstack([corners2[k], centres[k][None], (corners2[k] + np.roll(corners2[k], -1, 0)) / 2])
        ignore = np.repeat((owner == k)[None], len(samples), 0)
        blocked = segments_block(cam_xy, samples, occ_edges_a, occ_edges_b, ignore)
        # the vehicle's own far corners are hidden by itself: count only the near half
        near = np.argsort(np.hypot(*(samples - cam_xy).T))[: len(samples) // 2 + 1]
        occ = float(blocked[near].mean())
        p_det = (1 - phys.miss_prob) * (1 - occ ** 1.5) * (1.0 if dist < 60 else 0.75)
        if occ > 0.8 or rng.random() > p_det:
            continue
        bw, bh = cu2 - cu1, cv2 - cv1
        noise = rng.normal(0, 1, 4) * (phys.box_sigma_px + spec.box_sigma_rel * np.array([bw, bh, bw, bh]))
        b = np.array([cu1, cv1, cu2, cv2]) + noise
        b[[0, 2]] = np.clip(np.sort(b[[0, 2]]), 0, spec.width - 1)
        b[[1, 3]] = np.clip(np.sort(b[[1, 3]]), 0, spec.height - 1)
        score = float(np.clip(0.92 - 0.4 * occ + rng.normal(0, 0.05), 0.3, 0.99))
        depth = dist * (1 + rng.normal(0, depth_sigma_rel))
        boxes.append([*b, score, max(depth, 1.0)])
        ids.append(k)
        occl.append(occ)
    ids_arr = np.array(ids, np.int32)
    feats = synth_descriptors(rng, veh.colour[ids_arr] if len(ids) else np.zeros(0, int), response,
                              np.array(occl))
    fb, ff = _false_detections(rng, world, t, cam_T_world, K, spec, phys, response,
                               np.array(boxes, float).reshape(-1, 6), ids_arr, veh.colour)
    if len(fb):
        boxes.extend(fb.tolist())
        feats = np.vstack([feats, ff])
        ids_arr = np.concatenate([ids_arr, np.full(len(fb), -1, np.int32)])
    boxes_arr = np.array(boxes, np.float32).reshape(-1, 6)
    boxes_arr[:, 4] = calibrate_score(boxes_arr[:, 4], phys.score_slope, phys.score_bias)
    return boxes_arr, feats.astype(np.float32), ids_arr


def _false_detections(rng, world, t, cam_T_world, K, spec, phys, response, true_boxes, true_ids, colours):
    """False detections (F, 6) and their descriptors (F, 32): parts of real vehicles, roadside
    structure, and nothing (see the module docstring)."""
    n = int(rng.poisson(phys.false_detection_rate))
    if n == 0:
        return np.zeros((0, 6)), np.zeros((0, 32), np.float32)
    kind = rng.choice(3, n, p=[phys.false_on_vehicle_share, phys.false_on_structure_share,
                              1.0 - phys.false_on_vehicle_share - phys.false_on_structure_share])
    out, col, occ = [], [], []
    W, H = spec.width, spec.height
    sp = world.static_pts[np.isin(world.static_kind, (POLE, VEGETATION, FACADE))]
    pc = sp @ cam_T_world[:3, :3].T + cam_T_world[:3, 3] if len(sp) else np.zeros((0, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
    seen = (pc[:, 2] > 8) & (pc[:, 2] < 60) & (uv[:, 0] > 20) & (uv[:, 0] < W - 20) & (uv[:, 1] > 0) \
        & (uv[:, 1] < H) if len(pc) else np.zeros(0, bool)
    seen_idx = np.flatnonzero(seen)
    for k in kind:
        if k == 0 and len(true_boxes):                       # part of a real vehicle
            j = int(rng.integers(len(true_boxes)))
            u1, v1, u2, v2, _, depth = true_boxes[j]
            fw, fh = rng.uniform(0.35, 0.7), rng.uniform(0.45, 0.9)
            bw, bh = (u2 - u1) * fw, (v2 - v1) * fh
            cu = rng.uniform(u1 + bw / 2, max(u2 - bw / 2, u1 + bw / 2 + 1e-3))
            cv = rng.uniform(v1 + bh / 2, max(v2 - bh / 2, v1 + bh / 2 + 1e-3))
            out.append([cu - bw / 2, cv - bh / 2, cu + bw / 2, cv + bh / 2, rng.uniform(0.3, 0.75),
                        depth * (1 + rng.normal(0, phys.depth_sigma_rel))])
            col.append(int(colours[true_ids[j]]))
            occ.append(0.5)
            continue
        if k == 1 and len(seen_idx):                           # roadside structure
            i = int(rng.choice(seen_idx))
            d = float(pc[i, 2])
            bw, bh = K[0, 0] * rng.uniform(1.5, 4.0) / d, K[1, 1] * rng.uniform(1.2, 1.8) / d
            cu = uv[i, 0] + rng.normal(0, 0.15) * bw
            bottom = uv[i, 1] + rng.uniform(0.1, 0.4) * bh
            out.append([cu - bw / 2, bottom - bh, cu + bw / 2, bottom, rng.uniform(0.3, 0.7),
                        d * (1 + rng.normal(0, 0.12))])
            col.append(int(rng.integers(len(PALETTE))))
            occ.append(0.3)
            continue
        fd = rng.uniform(8, 70)                                # nothing: a shadow, a reflection
        fw = K[0, 0] * rng.uniform(1.6, 4.5) / fd
        fh = K[1, 1] * rng.uniform(1.3, 1.8) / fd
        fu = rng.uniform(0, max(W - fw, 1.0))
        fv = float(np.clip(K[1, 2] - fh * rng.uniform(0.2, 0.8), 0, max(H - fh, 0.0)))
        out.append([fu, fv, fu + fw, fv + fh, rng.uniform(0.3, 0.7), fd])
        col.append(int(rng.integers(len(PALETTE))))
        occ.append(0.0)
    fb = np.array(out, float)
    fb[:, [0, 2]] = np.clip(fb[:, [0, 2]], 0, W - 1)
    fb[:, [1, 3]] = np.clip(fb[:, [1, 3]], 0, H - 1)
    fb[:, 5] = np.maximum(fb[:, 5], 1.0)
    good = (fb[:, 2] - fb[:, 0] >= 4) & (fb[:, 3] - fb[:, 1] >= 4)
    feats = synth_descriptors(rng, np.array(col, int), response, np.array(occ))
    return fb[good], feats[good]
