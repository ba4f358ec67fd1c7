"""Sequences: one world per drive, every vehicle moving physically, observed frame after frame.

A sequence keeps one road layout (`world.build_world`), one set of vehicles with their
identities, sizes and colours, one physics sample and one pair of sensor mounts for its
whole length; only the sensor noise is new in every frame. Vehicles follow lane centrelines
(a slow lane-keeping wobble on top), turn at junctions on circular arcs at a speed their
lateral grip allows, and keep their distance to the vehicle ahead by the intelligent driver
model (IDM, integrated at 100 Hz); cross-road traffic waits at a red light. The Ego drives
straight on; the CAV drives ahead of it, comes the other way, or turns off at the junction;
a truck may overtake in the next lane and hide the vehicles both see for a while; a share
of the sequences has light traffic (stretches with 0-1 co-visible vehicles).

Each radar runs on its own clock: the Ego's frames at t0 + k / 20 Hz, the CAV's at a fixed
phase offset within half a period of it (capture stamps on the shared clock, DESIGN.md).

World frame: x east, y north, metres; headings from +x, counter-clockwise, radians. The
main road runs along y through the origin, the cross road (junction layouts) along x, or turned
about the origin by the world's skew when `mmatch sim --junction` draws oblique junctions
(`world.meta["junction_deg"]`): its lanes, its traffic and the turns onto it alike.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from mmatch.sim.geometry import pose_matrix, turned
from mmatch.sim.physics import PhysicsFamily, PhysicsSample, family
from mmatch.sim.scenario import FRAME_PERIOD_S, Scenario, _pairs, _view
from mmatch.sim.world import LANE_W, Vehicles, World, _colour, _lane_centres, build_world
from mmatch.types import Scene

SIM_DT_S = 0.01                 # integration step of the longitudinal dynamics
LIGHT_TRAFFIC_SHARE = 0.1      # sequences drawn with 1-3 other vehicles
TRUCK_SHARE = 0.5               # sequences with a truck overtaking next to the Ego
LATERAL_ACCEL_MPS2 = 2.5        # comfortable lateral acceleration in a turn
IDM_ACCEL, IDM_BRAKE, IDM_GAP_M, IDM_HEADWAY_S = 1.5, 2.5, 2.5, 1.2


@dataclass
class MovingVehicles(Vehicles):
    """A snapshot of moving vehicles at one instant: `pos0` is the position now, `yaw` the
    heading now, `speed` the speed now (m/s, along the heading), `yaw_rate` (V,) rad/s."""

    yaw_rate: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))


class Lane:
    """A path a vehicle drives along: a densely sampled centreline with arc length s (m)."""

    def __init__(self, xy: np.ndarray, turn_s: tuple[float, float] | None = None, turn_radius: float = 0.0):
        xy = np.asarray(xy, float)
        seg = np.diff(xy, axis=0)
        self.s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        self.xy = xy
        h = np.arctan2(seg[:, 1], seg[:, 0])
        self.heading = np.unwrap(np.concatenate([h, h[-1:]]))
        self.turn_s = turn_s                  # (start, end) arc length of the turn, or None
        self.turn_radius = turn_radius

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (n, 2), heading (n,) and curvature (n,) 1/m at arc lengths s (n,)."""
        s = np.clip(np.asarray(s, float), 0, self.length)
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        h = np.interp(s, self.s, self.heading)
        eps = 0.5
        k = (np.interp(s + eps, self.s, self.heading) - np.interp(s - eps, self.s, self.heading)) / (2 * eps)
        return np.column_stack([x, y]), h, k


def _straight(p: np.ndarray, heading: float, back: float, ahead: float, step: float = 0.5) -> np.ndarray:
    d = np.array([np.cos(heading), np.sin(heading)])
    u = np.arange(-back, ahead + step, step)
    return np.asarray(p, float) + u[:, None] * d


def turning_lane(start: np.ndarray, h_in: float, end_point: np.ndarray, h_out: float, radius: float,
                 back: float = 300.0, ahead: float = 300.0, step: float = 0.5) -> Lane:
    """A lane from `start` heading h_in that turns (by +-90 deg at a right-angle junction, by
    45-135 deg at an oblique one) on an arc of `radius` onto the line through `end_point` heading
    h_out (the arc is tangent to both lines)."""
    d_in = np.array([np.cos(h_in), np.sin(h_in)])
    d_out = np.array([np.cos(h_out), np.sin(h_out)])
    # corner where the two lines meet: start + a d_in = end_point - b d_out
    A = np.column_stack([d_in, d_out])
    a, _ = np.linalg.solve(A, np.asarray(end_point, float) - np.asarray(start, float))
    corner = np.asarray(start, float) + a * d_in
    turn = float(np.arctan2(d_in[0] * d_out[1] - d_in[1] * d_out[0], d_in @ d_out))   # signed, rad
    if abs(abs(turn) - np.pi / 2) < 1e-9:            # a right angle: exactly the quarter arc
        turn, reach = float(np.copysign(np.pi / 2, turn)), radius
    else:                                             # corner to either tangent point
        reach = radius * np.tan(abs(turn) / 2)
    t_in, t_out = corner - reach * d_in, corner + reach * d_out
    left = turn > 0
    centre = t_in + radius * (np.array([-d_in[1], d_in[0]]) if left else np.array([d_in[1], -d_in[0]]))
    a0 = np.arctan2(*(t_in - centre)[::-1])
    a1 = a0 + turn
    n_arc = max(int(abs(turn) * radius / step), 4)
    ang = np.linspace(a0, a1, n_arc + 1)
    arc = centre + radius * np.column_stack([np.cos(ang), np.sin(ang)])
    seg_in = _straight(t_in, h_in, back + max(a - reach, 0.0), 0.0, step)[:-1]
    seg_out = _straight(t_out, h_out, 0.0, ahead, step)[1:]
    xy = np.vstack([seg_in, arc, seg_out])
    s_turn0 = float(np.sum(np.hypot(*np.diff(np.vstack([seg_in, arc[:1]]), axis=0).T)))
    return Lane(xy, (s_turn0, s_turn0 + abs(turn) * radius), radius)


@dataclass
class Driver:
    """One vehicle's plan: its lane, where it starts (s0, m along the lane), its desired speed
    (m/s), a lateral wobble (amplitude m, wavelength m, phase rad) and a stop line (arc length
    of a red light, or inf)."""

    lane: Lane
    s0: float
    v_desired: float
    wobble: tuple[float, float, float] = (0.0, 100.0, 0.0)
    stop_s: float = float("inf")
    parked: bool = False

    def desired_speed(self, s: np.ndarray) -> np.ndarray:
        """Desired speed (m/s) at arc lengths s: slowed ahead of and through a turn."""
        v = np.full(np.shape(s), self.v_desired, float)
        if self.lane.turn_s is not None:
            v_turn = min(np.sqrt(LATERAL_ACCEL_MPS2 * self.lane.turn_radius), self.v_desired)
            a, b = self.lane.turn_s
            before = np.sqrt(v_turn ** 2 + 2 * 1.5 * np.maximum(a - s, 0.0))
            v = np.where(s < a, np.minimum(v, before), np.where(s <= b, v_turn, v))
        return v


class Drive:
    """Every vehicle's motion over one sequence (state integrated once, sampled at any time)."""

    def __init__(self, drivers: list[Driver], sizes: np.ndarray, colours: np.ndarray, duration_s: float):
        self.drivers = drivers
        self.size = np.asarray(sizes, float)
        self.colour = np.asarray(colours, int)
        n = len(drivers)
        steps = int(np.ceil(duration_s / SIM_DT_S)) + 2
        self.t = np.arange(steps) * SIM_DT_S
        s = np.array([d.s0 for d in drivers], float)
        # a vehicle starts at its desired speed, or slow enough to stop at its red light
        v = np.array([0.0 if d.parked else min(d.desired_speed(np.array([d.s0]))[0],
                                               np.sqrt(2 * IDM_BRAKE * max(d.stop_s - d.s0 - sz[0] / 2 - 1.0, 0.0)))
                      for d, sz in zip(drivers, self.size)], float)
        self.s = np.zeros((steps, n))
        self.v = np.zeros((steps, n))
        parked = np.array([d.parked for d in drivers])
        for k in range(steps):
            self.s[k], self.v[k] = s, v
            acc = self._idm(s, v)
            acc[parked] = 0.0
            v_new = np.maximum(v + acc * SIM_DT_S, 0.0)
            s = s + (v + v_new) / 2 * SIM_DT_S
            v = v_new

    def _pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        xy, h, k = np.zeros((len(s), 2)), np.zeros(len(s)), np.zeros(len(s))
        for i, d in enumerate(self.drivers):
            p, hh, kk = d.lane.at(np.array([s[i]]))
            amp, wl, ph = d.wobble
            off = amp * np.sin(2 * np.pi * s[i] / wl + ph)
            dh = np.arctan(amp * 2 * np.pi / wl * np.cos(2 * np.pi * s[i] / wl + ph))
            normal = np.array([-np.sin(hh[0]), np.cos(hh[0])])
            xy[i], h[i], k[i] = p[0] + off * normal, hh[0] + dh, kk[0]
        return xy, h, k

    def _idm(self, s: np.ndarray, v: np.ndarray) -> np.ndarray:
        """IDM acceleration (m/s^2) of every vehicle behind its leader (the nearest vehicle ahead
        within its lane's corridor, or a red light's stop line)."""
        xy, h, _ = self._pose(s)
        f = np.column_stack([np.cos(h), np.sin(h)])
        rel = xy[None, :, :] - xy[:, None, :]                         # (follower, other, 2)
        along = np.einsum("ija,ia->ij", rel, f)
        across = np.abs(rel[..., 0] * f[:, None, 1] - rel[..., 1] * f[:, None, 0])
        same_way = (f @ f.T) > 0.5
        ahead = (along > 0) & (across < 1.6) & same_way
        np.fill_diagonal(ahead, False)
        half = (self.size[:, 0][:, None] + self.size[:, 0][None, :]) / 2
        gap = np.where(ahead, along - half, np.inf)
        lead = np.argmin(gap, axis=1)
        g = gap[np.arange(len(s)), lead]
        dv = v - np.where(np.isfinite(g), v[lead], v)
        stop = np.array([d.stop_s for d in self.drivers]) - s - self.size[:, 0] / 2
        use_stop = (stop > -1.0) & (stop < g)
        g = np.where(use_stop, np.maximum(stop, 0.1), g)
        dv = np.where(use_stop, v, dv)
        v0 = np.array([max(d.desired_speed(np.array([s[i]]))[0], 0.1) for i, d in enumerate(self.drivers)])
        star = IDM_GAP_M + v * IDM_HEADWAY_S + v * dv / (2 * np.sqrt(IDM_ACCEL * IDM_BRAKE))
        inter = np.where(np.isfinite(g), (np.maximum(star, 0) / np.maximum(g, 0.1)) ** 2, 0.0)
        acc = IDM_ACCEL * (1 - (v / v0) ** 4 - inter)
        return np.maximum(acc, -8.0)

    def vehicles_at(self, t: float) -> MovingVehicles:
        """Every vehicle at time t (s since the drive's start)."""
        k = float(np.clip(t / SIM_DT_S, 0, len(self.t) - 1.000001))
        i, w = int(k), k - int(k)
        s = self.s[i] * (1 - w) + self.s[i + 1] * w
        v = self.v[i] * (1 - w) + self.v[i + 1] * w
        xy, h, curv = self._pose(s)
        parked = np.array([d.parked for d in self.drivers])
        return MovingVehicles(pos0=xy, yaw=h, speed=v, size=self.size, colour=self.colour, parked=parked,
                              yaw_rate=v * curv)


class SequenceScenario(Scenario):
    """A Scenario whose world is a snapshot of moving vehicles: a radar on a turning vehicle
    moves with the vehicle's centre velocity plus the yaw rate times its lever arm."""

    def radar_pose(self, world: World, role: str, t: float) -> tuple[np.ndarray, np.ndarray]:
        k = world.ego if role == "ego" else world.cav
        veh = world.vehicles
        m = self.mounts[role]
        f = np.array([np.cos(veh.yaw[k]), np.sin(veh.yaw[k])])
        arm = f * (veh.size[k, 0] / 2 - 0.1)
        xy = veh.position(t)[k] + arm
        vel = veh.velocity[k].copy()
        if isinstance(veh, MovingVehicles):
            vel += veh.yaw_rate[k] * np.array([-arm[1], arm[0]])
        return pose_matrix(xy, veh.yaw[k] + m.radar_yaw_offset, m.radar_height), vel


# ---------------------------------------------------------------- the cast of one drive
def _forward_lanes(lanes: int, two_way: bool) -> tuple[np.ndarray, np.ndarray]:
    c = _lane_centres(lanes)
    d = np.where(c > 0, 1, -1) if two_way else np.ones(lanes, int)
    if two_way and lanes % 2 == 1:
        d[lanes // 2] = 1
    return c, d


def _main_lane(x: float, heading: float) -> Lane:
    return Lane(_straight(np.array([x, 0.0]), heading, 500.0, 500.0))


def _turn_off(rng: np.random.Generator, x: float, heading: float, road: str, centres: np.ndarray,
              dirs: np.ndarray, half_w: float, skew: float = 0.0) -> Lane | None:
    """A main-road lane (at x, heading +-pi/2) that turns onto an outbound cross-road lane (the
    cross road turned by `skew` rad about the junction), or None when the layout has no cross
    road on the side it would turn to."""
    going_north = np.sin(heading) > 0
    sides = [-1, 1] if road == "intersection" else [-1]
    side = int(rng.choice(sides))                                    # the cross road's side (x sign)
    h_out = np.pi if side < 0 else 0.0
    # outbound lanes on that side: heading away from the junction (d = side), at y = -d |c|
    out_c = np.abs(centres[dirs > 0]) if len(centres[dirs > 0]) else np.abs(centres)
    y_out = -side * float(rng.choice(out_c))
    turning_left = (side < 0) == going_north
    radius = float(rng.uniform(8, 14)) if turning_left else float(rng.uniform(5, 8))
    start = np.array([x, -np.sign(np.sin(heading)) * (half_w + 40.0)])
    end = turned(np.array([side * (half_w + 40.0), y_out]), skew)
    try:
        return turning_lane(start, heading, end, h_out + skew, radius)
    except np.linalg.LinAlgError:
        return None


def _cross_lane(side: int, d: int, c: float, stop_at: float, skew: float = 0.0) -> tuple[Lane, float]:
    """A cross-road lane on the `side` of the junction driving in direction d (+1 east, -1 west) at
    lane offset c, the cross road turned by `skew` rad about the junction; returns it and the arc
    length of its stop line (inf when it drives away)."""
    heading = 0.0 if d > 0 else np.pi
    y = -d * abs(c)
    lane = Lane(turned(_straight(np.array([0.0, y]), heading, 500.0, 500.0), skew))
    inbound = d == -side
    return lane, (500.0 - stop_at if inbound else float("inf"))


def _sizes(rng: np.random.Generator, n: int, truck: bool = False) -> np.ndarray:
    if truck:
        return np.array([[rng.uniform(9.0, 12.0), rng.uniform(2.4, 2.55), rng.uniform(3.2, 3.8)]])
    kind = rng.random(n)
    length = np.where(kind < 0.88, rng.uniform(4.0, 5.0, n), rng.uniform(6.5, 9.0, n))
    width = np.where(kind < 0.88, rng.uniform(1.75, 2.0, n), rng.uniform(2.2, 2.5, n))
    height = np.where(kind < 0.88, rng.uniform(1.4, 1.8, n), rng.uniform(2.6, 3.4, n))
    return np.column_stack([length, width, height])


def _wobble(rng: np.random.Generator) -> tuple[float, float, float]:
    return float(rng.uniform(0.05, 0.25)), float(rng.uniform(60, 140)), float(rng.uniform(0, 2 * np.pi))


@dataclass
class Cast:
    """The drivers of one sequence with what they are (for the meta record)."""

    drivers: list[Driver]
    sizes: np.ndarray
    colours: np.ndarray
    story: dict


def draw_cast(rng: np.random.Generator, world: World, duration_s: float, light: bool = False) -> Cast:
    """Ego (index 0, straight on), CAV (index 1), maybe a truck, other traffic (1-3 vehicles when
    `light`) and parked cars."""
    road, lanes = world.road, world.lanes
    hard = world.meta.get("mode") == "hard"
    centres, dirs = _forward_lanes(lanes, hard)
    half_w = lanes * LANE_W / 2
    junction = road != "straight"
    skew = float(np.radians(world.meta.get("junction_deg", 90.0) - 90.0))
    # how far along the main road the cross road reaches from the junction (its kerb at the
    # main road's kerb line; half_w at 90 deg)
    cross_reach = half_w / np.cos(skew) + (half_w + 1.3) * abs(np.tan(skew))
    drivers: list[Driver] = []
    sizes: list[np.ndarray] = []
    story: dict = {}
    fwd = np.flatnonzero(dirs > 0)
    back = np.flatnonzero(dirs < 0)

    # CAV: ahead in the same direction (maybe turning off at the junction within the drive), or
    # oncoming; the Ego behind it, straight on along +y
    relation = "same" if not hard or not len(back) else str(rng.choice(["same", "opposite"], p=[0.6, 0.4]))
    turn = junction and rng.random() < 0.6
    v_ego, v_cav = float(rng.uniform(8, 15)), float(rng.uniform(8, 15))
    ego_lane = int(rng.choice(fwd))
    cav_lane = int(rng.choice(fwd if relation == "same" else back))
    heading = np.pi / 2 if relation == "same" else -np.pi / 2
    horizon = min(duration_s, 4.0)
    gap = float(rng.uniform(15, 40) if relation == "same" else rng.uniform(40, 90))
    lane = _turn_off(rng, centres[cav_lane], heading, road, centres, dirs, half_w, skew) if turn else None
    if lane is not None:
        s_cav = lane.turn_s[0] - v_cav * float(rng.uniform(0.05, 0.45)) * horizon
        y_cav = float(lane.at(np.array([s_cav]))[0][0, 1])
    else:
        turn = False
        lane = _main_lane(centres[cav_lane], heading)
        if junction:          # the drive crosses the junction
            y_cav = float(-rng.uniform(0.2, 0.8) * v_ego * horizon - rng.uniform(5, 25)) + gap
        else:
            y_cav = float(rng.uniform(-50, 50)) + gap
        s_cav = 500.0 + (y_cav if relation == "same" else -y_cav)
    y_ego = y_cav - gap
    drivers.append(Driver(_main_lane(centres[ego_lane], np.pi / 2), 500.0 + y_ego, v_ego, _wobble(rng)))
    sizes.append(_sizes(rng, 1))
    drivers.append(Driver(lane, s_cav, v_cav, _wobble(rng)))
    sizes.append(_sizes(rng, 1))
    story.update(relation=relation, cav_turns=bool(turn))

    # a truck overtaking in the lane next to the Ego
    neighbours = [i for i in (ego_lane - 1, ego_lane + 1) if 0 <= i < lanes]
    truck = bool(neighbours) and rng.random() < TRUCK_SHARE
    if truck:
        tl = int(rng.choice(neighbours))
        th = np.pi / 2 if dirs[tl] > 0 else -np.pi / 2
        if dirs[tl] > 0:
            s_t, v_t = 500.0 + y_ego - float(rng.uniform(2, 15)), v_ego + float(rng.uniform(3, 7))
        else:
            s_t, v_t = 500.0 - (y_ego + float(rng.uniform(30, 60))), float(rng.uniform(8, 14))
        drivers.append(Driver(_main_lane(centres[tl], th), s_t, v_t, _wobble(rng)))
        sizes.append(_sizes(rng, 1, truck=True))
    story["truck"] = truck

    # other traffic on every lane, gaps of at least 9 m along a lane
    n_other = int(rng.integers(1, 4)) if light else (int(rng.integers(6, 17)) if hard else int(rng.integers(2, 6)))
    story["light_traffic"] = bool(light)
    placed: list[tuple[float, float]] = []
    for d in drivers:
        xy, _, _ = d.lane.at(np.array([d.s0]))
        placed.append((float(xy[0, 0]), float(xy[0, 1])))
    tries = 0
    added = 0
    while added < n_other and tries < 400:
        tries += 1
        on_cross = junction and rng.random() < 0.3
        v0 = float(rng.uniform(8, 15))
        stop = float("inf")
        if on_cross:
            side = int(rng.choice([-1, 1])) if road == "intersection" else -1
            dd = int(rng.choice([-1, 1]))
            c = float(rng.choice(np.abs(centres)))
            lane, stop = _cross_lane(side, dd, c, half_w / np.cos(skew) + 2.0, skew)
            x = side * float(rng.uniform(half_w + 6, 80))
            s0 = 500.0 + (x if dd > 0 else -x)
        else:
            li = int(rng.integers(lanes))
            h = np.pi / 2 if dirs[li] > 0 else -np.pi / 2
            y = y_ego + float(rng.uniform(-30, 90))
            lane = None
            if junction and rng.random() < 0.3:
                lane = _turn_off(rng, centres[li], h, road, centres, dirs, half_w, skew)
            if lane is None:
                lane = _main_lane(centres[li], h)
                s0 = 500.0 + (y if dirs[li] > 0 else -y)
            else:
                s0 = float(abs(y - lane.xy[0, 1]))
                if s0 >= lane.turn_s[0]:
                    continue
        xy, _, _ = lane.at(np.array([s0]))
        if any(np.hypot(xy[0, 0] - p[0], xy[0, 1] - p[1]) < 9.0 for p in placed):
            continue
        drivers.append(Driver(lane, s0, v0, _wobble(rng), stop_s=stop))
        sizes.append(_sizes(rng, 1))
        placed.append((float(xy[0, 0]), float(xy[0, 1])))
        added += 1
    # parked cars along the curb
    n_parked = int(rng.integers(2, 6)) if world.meta.get("urban") else int(rng.integers(0, 2))
    for _ in range(n_parked * 3):
        if sum(d.parked for d in drivers) >= n_parked:
            break
        side = float(rng.choice([-1, 1]))
        y = y_ego + float(rng.uniform(-20, 90))
        if junction and abs(y) < cross_reach + 12:
            continue
        if any(np.hypot(side * (half_w + 1.3) - p[0], y - p[1]) < 8.0 for p in placed):
            continue
        lane = Lane(_straight(np.array([side * (half_w + 1.3), y]), np.pi / 2 + rng.normal(0, 0.03), 5.0, 5.0))
        drivers.append(Driver(lane, 5.0, 0.0, parked=True))
        sizes.append(_sizes(rng, 1))
        placed.append((side * (half_w + 1.3), y))
    n = len(drivers)
    return Cast(drivers, np.vstack(sizes), _colour(rng, n), story)


# ---------------------------------------------------------------- a sequence of scenes
@dataclass
class Sequence:
    """One drive: its world layout, the vehicles' motion, the observers and the clocks."""

    name: str
    world: World
    drive: Drive
    scenario: SequenceScenario
    t0: float
    cav_offset_s: float
    meta: dict
    seed: int

    def world_at(self, t: float) -> World:
        """The world with every vehicle where it is at time t (s on the drive's clock)."""
        return dataclasses.replace(self.world, vehicles=self.drive.vehicles_at(t))

    def scene(self, k: int) -> Scene:
        """Frame k: the Ego's frame captured at t0 + k / 20 Hz, the CAV's at its phase offset."""
        t_e = self.t0 + k * FRAME_PERIOD_S
        t_c = t_e + self.cav_offset_s
        sc = self.scenario
        w_e, w_c = self.world_at(t_e), self.world_at(t_c)
        ego = sc._observe(w_e, "ego", 0.0, t_e, np.random.default_rng([self.seed, k, 2]))
        cav = sc._observe(w_c, "cav", 0.0, t_c, np.random.default_rng([self.seed, k, 3]))
        gt = np.linalg.inv(ego.world_T_radar) @ cav.world_T_radar
        pairs = _pairs(ego.box_ids, cav.box_ids)
        veh = w_e.vehicles
        R = ego.world_T_radar[:2, :2]
        seen = sorted({int(i) for i in np.concatenate([ego.box_ids, cav.box_ids]) if i >= 0})
        vel = {str(i): (R.T @ veh.velocity[i]).tolist() for i in seen}
        pos = {str(i): (R.T @ (veh.pos0[i] - ego.world_T_radar[:2, 3])).tolist() for i in seen}
        meta = dict(self.meta, frame=int(k), covisible=int(len(pairs)),
                    ego_velocity=ego.velocity.tolist(), cav_velocity=cav.velocity.tolist(),
                    ego_yaw_rate=float(veh.yaw_rate[0]), cav_yaw_rate=float(veh.yaw_rate[1]),
                    vehicle_velocity=vel, vehicle_position=pos)
        return Scene(ego=_view(ego), cav=_view(cav), gt_T_ego_cav=gt, gt_pairs=pairs, meta=meta,
                     name=f"{self.name}_{k:05d}")


def make_sequence(seed: int, index: int, frames: int, mode: str = "hard",
                  physics: str | PhysicsFamily | PhysicsSample = "nominal", tries: int = 12) -> Sequence:
    """Sequence `index` of the data set `seed`: `frames` frame pairs of one drive (see the module doc).

    The physics is drawn once for the sequence. A sequence with normal traffic is drawn again
    (up to `tries` times, keeping the best) until both cameras see at least two common vehicles
    at its start and its middle; light-traffic ones are kept as drawn.
    """
    if mode not in ("easy", "hard", "mixed"):
        raise ValueError(f"mode must be easy, hard or mixed, not {mode!r}")
    fam = physics if isinstance(physics, PhysicsFamily) else None
    if isinstance(physics, PhysicsSample):
        phys, fam_name = physics, "sample"
    else:
        fam = fam or family(physics)
        phys, fam_name = fam.draw(np.random.default_rng([seed, index, 77])), fam.name
    duration = frames * FRAME_PERIOD_S + 0.5
    light = bool(np.random.default_rng([seed, index, 56]).random() < LIGHT_TRAFFIC_SHARE)
    best = None
    for attempt in range(tries):
        rng = np.random.default_rng([seed, index, attempt, 55])
        world = build_world(rng, mode)
        cast = draw_cast(rng, world, duration, light)
        drive = Drive(cast.drivers, cast.sizes, cast.colours, duration)
        sc_seed = int(rng.integers(2**31))
        sc = SequenceScenario(sc_seed, "hard", physics=phys)
        world = dataclasses.replace(world, ego=0, cav=1, relation=cast.story["relation"])
        n = min(sc._common_detections(dataclasses.replace(world, vehicles=drive.vehicles_at(t)), 0.0)
                for t in (0.1, duration / 2))
        cand = (n, attempt, world, drive, sc, cast, rng)
        if best is None or n > best[0]:
            best = cand
        if n >= 2 or cast.story["light_traffic"]:
            best = cand
            break
    n, attempt, world, drive, sc, cast, rng = best
    name = f"s{seed}-{index:04d}"
    meta = dict(world.meta, **cast.story, sequence=name, seed=seed, index=index, attempt=attempt,
                difficulty=world.meta["mode"], physics=fam_name, physics_values=phys.as_dict(),
                parked_ids=[i for i, d in enumerate(cast.drivers) if d.parked], frame_period_s=FRAME_PERIOD_S)
    return Sequence(name=name, world=world, drive=drive, scenario=sc, t0=float(rng.uniform(0.05, 0.3)),
                    cav_offset_s=float(rng.uniform(-FRAME_PERIOD_S / 2, FRAME_PERIOD_S / 2)), meta=meta, seed=sc_seed)
