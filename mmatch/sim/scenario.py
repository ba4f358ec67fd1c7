"""A simulated world over time, seen by the Ego and the CAV (each with its own pose and clock).

`make_scenario(seed, mode).observe(role, t)` renders what one vehicle's radar and camera
report at time t; vehicles move between calls. Time is cut into episodes of
`EPISODE_S` seconds, each a freshly drawn road and traffic, so a long run never drives
off the map. `make_scene` renders one Ego/CAV frame pair as a `Scene` with ground truth.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
from dataclasses import dataclass

import numpy as np

from mmatch.sim.camera import CameraResponse, CameraSpec, camera_pose_from, observe_camera
from mmatch.sim.geometry import pose_matrix
from mmatch.sim.physics import PhysicsFamily, PhysicsSample, family
from mmatch.sim.radar import RadarSpec, angle_spec, observe_radar
from mmatch.sim.radar_errors import AngleErrorSpec
from mmatch.sim.world import World, build_world
from mmatch.types import CameraModel, Scene, View

EPISODE_S = 10.0
ROLES = ("ego", "cav")
FRAME_PERIOD_S = 0.05


@dataclass(frozen=True)
class Mount:
    """How one vehicle carries its sensors (fixed for the vehicle's lifetime)."""

    radar_height: float
    radar_yaw_offset: float        # rad, CCW; the radar's boresight is off the vehicle axis
    cam_offset: tuple[float, float, float]   # right, back from the radar, up (m)
    cam_pitch: float               # rad, positive looks down
    focal: float                   # px
    principal: tuple[float, float]
    response: CameraResponse       # this camera's exposure and colour response
    depth_sigma_rel: float         # monocular depth error of its detector
    extrinsic_error: np.ndarray    # 4x4: the calibrated T_cam_radar is extrinsic_error @ the true one
    array: AngleErrorSpec          # the radar's angle error constants (its own calibration bias)


def _small_rigid(rng: np.random.Generator, max_rot_deg: float, max_trans_m: float) -> np.ndarray:
    """A 4x4 rotation by up to max_rot_deg about a random axis and a shift of up to max_trans_m."""
    axis = rng.normal(0, 1, 3)
    axis /= np.linalg.norm(axis)
    a = np.radians(rng.uniform(0, max_rot_deg))
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + np.sin(a) * Kx + (1 - np.cos(a)) * Kx @ Kx
    d = rng.normal(0, 1, 3)
    T[:3, 3] = d / np.linalg.norm(d) * rng.uniform(0, max_trans_m)
    return T


def draw_mount(rng: np.random.Generator, spec: CameraSpec, phys: PhysicsSample, side: float = 1.0) -> Mount:
    """One vehicle's sensor mounting under the scene's physics; side (+1 / -1) splits the two
    cameras' colour-response difference between them."""
    yaw_sigma = phys.radar_yaw_error_deg
    return Mount(radar_height=float(rng.uniform(0.4, 0.9)),
                 radar_yaw_offset=float(np.radians(np.clip(rng.normal(0, yaw_sigma), -2.5 * yaw_sigma,
                                                           2.5 * yaw_sigma))),
                 cam_offset=(float(rng.normal(0, 0.1)), float(rng.uniform(1.5, 2.2)), float(rng.uniform(0.5, 0.9))),
                 cam_pitch=float(np.radians(rng.uniform(0, 3))),
                 focal=float(rng.uniform(900, 1100)) * phys.camera_focal_scale,
                 principal=(spec.width / 2 + float(rng.normal(0, 8)), spec.height / 2 + float(rng.normal(0, 8))),
                 response=CameraResponse(gain=float(rng.uniform(0.75, 1.2)), hue_shift=side * phys.camera_hue_shift / 2,
                                         saturation_gain=float(phys.camera_saturation_gain ** (side / 2)),
                                         pixels=int(phys.descriptor_pixels)),
                 depth_sigma_rel=float(phys.depth_sigma_rel * rng.uniform(0.75, 1.25)),
                 extrinsic_error=_small_rigid(rng, phys.extrinsic_rot_err_deg, phys.extrinsic_trans_err_m),
                 array=angle_spec(phys, rng))


@dataclass
class Observation:
    """One vehicle's sensor output at one time, plus its ground truth."""

    points: np.ndarray
    boxes: np.ndarray
    features: np.ndarray
    camera: CameraModel
    radar_height: float
    stamp: float
    point_labels: np.ndarray
    box_ids: np.ndarray
    world_T_radar: np.ndarray
    velocity: np.ndarray


class Scenario:
    """A world that moves over time, observed by the Ego (vehicle 0) and the CAV (vehicle 1).

    Every EPISODE_S seconds a new world is drawn. covisible > 0 redraws an episode's world
    (up to `tries` times, keeping the best) until both cameras detect at least that many
    common vehicles at its start and middle, as the scene files ask of their frames; the live simulator uses it so that two vehicles
    have something to fuse, and builds the next episode's world in the background
    (drawing one takes 0.1-0.5 s, longer than a frame) in a child process.
    """

    def __init__(self, seed: int, mode: str = "mixed", radar: RadarSpec = RadarSpec(),
                 camera: CameraSpec = CameraSpec(), covisible: int = 0, tries: int = 20,
                 physics: str | PhysicsFamily | PhysicsSample = "nominal") -> None:
        if mode not in ("easy", "hard", "mixed"):
            raise ValueError(f"mode must be easy, hard or mixed, not {mode!r}")
        self.seed, self.mode, self.radar, self.cam = seed, mode, radar, camera
        self.covisible, self.tries = covisible, tries
        if isinstance(physics, PhysicsSample):
            self.phys = physics
        else:
            fam = physics if isinstance(physics, PhysicsFamily) else family(physics)
            self.phys = fam.draw(np.random.default_rng([seed, 8]))
        rng = np.random.default_rng([seed, 7])
        self.mounts = {role: draw_mount(rng, camera, self.phys, 1.0 if role == "ego" else -1.0) for role in ROLES}
        self._worlds: dict[int, World] = {}
        self._lock = threading.Lock()
        self._pending: dict[int, threading.Thread] = {}

    def world(self, episode: int) -> World:
        pending = self._pending.get(episode)
        if pending is not None:
            pending.join()
        with self._lock:
            w = self._worlds.get(episode)
        if w is None:
            w = self._build(episode)
            self._store(episode, w)
        return w

    def _store(self, episode: int, world: World) -> None:
        with self._lock:
            while len(self._worlds) > 4:
                self._worlds.pop(next(iter(self._worlds)))
            self._worlds[episode] = world
            self._pending.pop(episode, None)

    def _build(self, episode: int) -> World:
        world = build_world(np.random.default_rng([self.seed, episode, 1]), self.mode)
        if self.covisible <= 0:
            return world
        best, best_n = world, self._covisibility(world)
        for attempt in range(1, self.tries):
            if best_n >= self.covisible:
                break
            world = build_world(np.random.default_rng([self.seed, episode, 1, attempt]), self.mode)
            n = self._covisibility(world)
            if n > best_n:
                best, best_n = world, n
        return best

    def _covisibility(self, world: World) -> int:
        """Fewest vehicles both cameras detect, at the episode's start and middle."""
        return min(self._common_detections(world, t) for t in (0.0, EPISODE_S / 2))

    def _common_detections(self, world: World, t: float = 0.0) -> int:
        ids = []
        for role in ROLES:
            own = world.ego if role == "ego" else world.cav
            w_T_r, _ = self.radar_pose(world, role, t)
            cam, T_cam_radar = self.camera_model(role)
            m = self.mounts[role]
            _, _, got = observe_camera(world, t, w_T_r @ np.linalg.inv(T_cam_radar), cam.K, own,
                                       np.random.default_rng([self.seed, 5]), self.cam, m.depth_sigma_rel,
                                       m.response, self.phys)
            ids.append(set(got[got >= 0].tolist()))
        return len(ids[0] & ids[1])

    def prefetch(self, episode: int) -> None:
        """Start drawing `episode`'s world ahead of time (no-op if drawn or pending).

        The draw runs in a child process (`python -m mmatch.sim.worldgen`), waited for by a
        thread that only blocks on I/O: drawing and checking a world is Python-heavy
        (0.1-0.5 s) and would hold the interpreter lock against the vehicle's frame loop.
        If the child fails, the thread draws the world itself.
        """
        with self._lock:
            if episode in self._worlds or episode in self._pending:
                return
            th = threading.Thread(target=self._draw_elsewhere, args=(episode,), name=f"sim-world-{episode}",
                                  daemon=True)
            self._pending[episode] = th
        th.start()

    def _draw_elsewhere(self, episode: int) -> None:
        args = [sys.executable, "-m", "mmatch.sim.worldgen", str(self.seed), self.mode, str(self.covisible),
                str(self.tries), str(episode)]
        try:
            out = subprocess.run(args, capture_output=True, timeout=60, check=True,
                                 preexec_fn=_lowest_priority).stdout
            world = pickle.loads(out)
        except (OSError, subprocess.SubprocessError, pickle.UnpicklingError, EOFError):
            world = self._build(episode)
        self._store(episode, world)

    def close(self) -> None:
        """Nothing to release (kept for callers that close their sources)."""

    def radar_pose(self, world: World, role: str, t: float) -> tuple[np.ndarray, np.ndarray]:
        """world_T_radar (4x4) and the radar's world velocity (2,) of `role` at local time t."""
        k = world.ego if role == "ego" else world.cav
        veh = world.vehicles
        m = self.mounts[role]
        f = np.array([np.cos(veh.yaw[k]), np.sin(veh.yaw[k])])
        xy = veh.position(t)[k] + f * (veh.size[k, 0] / 2 - 0.1)
        return pose_matrix(xy, veh.yaw[k] + m.radar_yaw_offset, m.radar_height), veh.velocity[k]

    def camera_model(self, role: str) -> tuple[CameraModel, np.ndarray]:
        """The role's CameraModel as calibrated (with the extrinsic error) and the true T_cam_radar."""
        m = self.mounts[role]
        # camera pose in the radar frame: vehicle axes are the radar axes turned back by the mount yaw
        veh_T_radar = pose_matrix(np.zeros(2), np.pi / 2 + m.radar_yaw_offset, 0.0)
        veh_T_cams = pose_matrix(np.array([m.cam_offset[0], -m.cam_offset[1]]), np.pi / 2, m.cam_offset[2])
        veh_T_cam = camera_pose_from(veh_T_cams, m.cam_pitch)
        T_cam_radar = np.linalg.inv(veh_T_cam) @ veh_T_radar
        K = np.array([[m.focal, 0, m.principal[0]], [0, m.focal, m.principal[1]], [0, 0, 1.0]])
        believed = m.extrinsic_error @ T_cam_radar
        return CameraModel(K=K, image_size=(self.cam.width, self.cam.height), T_cam_radar=believed), T_cam_radar

    def observe(self, role: str, t: float) -> Observation:
        """Render `role`'s radar frame and camera detections at time t (s)."""
        episode = int(np.floor(t / EPISODE_S))
        if self.covisible > 0 and t - episode * EPISODE_S > EPISODE_S / 4:
            self.prefetch(episode + 1)
        return self._observe(self.world(episode), role, t - episode * EPISODE_S, t,
                             np.random.default_rng([self.seed, episode, ROLES.index(role) + 2,
                                                    int(round(t * 1e6)) % 2**32]))

    def _observe(self, world: World, role: str, t_local: float, stamp: float,
                 rng: np.random.Generator) -> Observation:
        own = world.ego if role == "ego" else world.cav
        w_T_r, vel = self.radar_pose(world, role, t_local)
        m = self.mounts[role]
        pts, labels = observe_radar(world, t_local, w_T_r, vel, own, rng, self.radar, self.phys, m.array)
        cam, T_cam_radar = self.camera_model(role)
        w_T_cam = w_T_r @ np.linalg.inv(T_cam_radar)
        boxes, feats, ids = observe_camera(world, t_local, w_T_cam, cam.K, own, rng, self.cam,
                                           m.depth_sigma_rel, m.response, self.phys)
        v_radar = (w_T_r[:3, :3].T @ np.array([vel[0], vel[1], 0.0]))[:2]
        return Observation(points=pts, boxes=boxes, features=feats, camera=cam,
                           radar_height=m.radar_height, stamp=stamp, point_labels=labels,
                           box_ids=ids, world_T_radar=w_T_r, velocity=v_radar)


def _lowest_priority() -> None:
    """In the world-drawing child: yield the CPU to the vehicle processes (it has seconds)."""
    os.nice(19)


def make_scenario(seed: int, mode: str = "mixed", covisible: int = 0,
                  physics: str | PhysicsFamily | PhysicsSample = "nominal") -> Scenario:
    """The scenario of `seed` in `mode` ('easy', 'hard' or 'mixed'); see Scenario for covisible."""
    return Scenario(seed, mode, covisible=covisible, physics=physics)


def _pairs(ego_ids: np.ndarray, cav_ids: np.ndarray) -> np.ndarray:
    pairs = [(i, j) for i, a in enumerate(ego_ids) if a >= 0 for j, b in enumerate(cav_ids) if b == a]
    return np.array(pairs, np.int32).reshape(-1, 2)


def make_scene(seed: int, index: int, mode: str, physics: str | PhysicsFamily = "nominal",
               min_pairs: int = 2, tries: int = 30) -> Scene:
    """Scene `index` of the data set `seed`: an Ego/CAV frame pair with ground truth.

    Each scene is its own episode with its own mounts and physics (drawn from `physics`).
    A share `few_covisible_share` of the scenes is drawn with fewer than `min_pairs` common
    detections (a truck between the two, a CAV turning away: real traffic has them), the
    others with at least `min_pairs`, as in the paper's evaluation set; draws are repeated
    up to `tries` times and the last kept otherwise. `meta` records the physics drawn and
    the number of co-visible pairs.
    """
    fam = physics if isinstance(physics, PhysicsFamily) else family(physics)
    first = fam.draw(np.random.default_rng([seed, index, 77]))
    want_few = bool(np.random.default_rng([seed, index, 78]).random() < first.few_covisible_share)
    scene = None
    for attempt in range(tries):
        sc_seed = int(np.random.default_rng([seed, index, attempt]).integers(2**31))
        phys = first if attempt == 0 else fam.draw(np.random.default_rng([seed, index, attempt, 77]))
        sc = Scenario(sc_seed, mode, physics=phys)
        world = sc.world(0)
        rng = np.random.default_rng([seed, index, attempt, 99])
        dt = float(rng.uniform(-FRAME_PERIOD_S / 2, FRAME_PERIOD_S / 2))
        t0 = float(rng.uniform(0, 0.2))
        ego = sc._observe(world, "ego", t0, t0, rng)
        cav = sc._observe(world, "cav", t0 + dt, t0 + dt, rng)
        gt = np.linalg.inv(ego.world_T_radar) @ cav.world_T_radar
        pairs = _pairs(ego.box_ids, cav.box_ids)
        meta = dict(world.meta, seed=seed, index=index, attempt=attempt,
                    parked_ids=np.flatnonzero(world.vehicles.parked).tolist(),
                    ego_velocity=ego.velocity.tolist(), cav_velocity=cav.velocity.tolist(),
                    difficulty=world.meta["mode"], physics=fam.name, physics_values=phys.as_dict(),
                    covisible=int(len(pairs)))
        scene = Scene(ego=_view(ego), cav=_view(cav), gt_T_ego_cav=gt, gt_pairs=pairs, meta=meta,
                      name=f"scene_{index:05d}")
        if (len(pairs) < min_pairs) == want_few:
            break
    return scene


def scene_from_world(world: World, seed: int, physics: str | PhysicsFamily | PhysicsSample = "nominal",
                     t0: float = 0.1, name: str = "scene") -> Scene:
    """An Ego/CAV frame pair of a given world (vehicles `world.ego` and `world.cav`), for tests
    and hand-made situations; the mounts and noise come from `seed` and the physics."""
    sc = Scenario(seed, "hard", physics=physics)
    sc._store(0, world)
    rng = np.random.default_rng([seed, 99])
    dt = float(rng.uniform(-FRAME_PERIOD_S / 2, FRAME_PERIOD_S / 2))
    ego = sc._observe(world, "ego", t0, t0, rng)
    cav = sc._observe(world, "cav", t0 + dt, t0 + dt, rng)
    pairs = _pairs(ego.box_ids, cav.box_ids)
    meta = dict(world.meta, seed=seed, parked_ids=np.flatnonzero(world.vehicles.parked).tolist(),
                covisible=int(len(pairs)))
    return Scene(ego=_view(ego), cav=_view(cav), gt_T_ego_cav=np.linalg.inv(ego.world_T_radar) @ cav.world_T_radar,
                 gt_pairs=pairs, meta=meta, name=name)


def _view(o: Observation) -> View:
    return View(points=o.points, boxes=o.boxes, features=o.features, camera=o.camera, stamp=o.stamp,
                radar_height=o.radar_height, point_labels=o.point_labels, box_ids=o.box_ids)
