"""Roads, roadside structures and traffic of one simulated episode (world frame, metres).

Layouts follow the paper's modes: `easy` is one straight road with all traffic in one
direction and light traffic; `hard` mixes straight roads, 4-way intersections and
T-junctions, same / opposite / perpendicular headings, heavy traffic, 2-10 lanes and
8-20 m/s. Roadsides repeat themselves on purpose (guardrail posts every 2 m, poles at a
fixed pitch on both sides, parallel facades): that is what defeats background-only
alignment on real roads.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from mmatch.sim.geometry import turned

LANE_W = 3.5
ROAD_HALF_LEN = 450.0
# dense traffic: "LO-HI" other vehicles instead of the mode's 1-4 (easy) or 6-20 (hard); set by
# `mmatch sim --vehicles LO-HI` (an environment variable so that worker processes see it too)
TRAFFIC_ENV = "MMATCH_SIM_OTHER_VEHICLES"
STOPPED_ENV = "MMATCH_SIM_STOPPED"
JUNCTION_ENV = "MMATCH_SIM_JUNCTION_DEG"

# static scatterer kinds
GUARDRAIL, FACADE, POLE, VEGETATION = 0, 1, 2, 3
# colours: index into sim.camera.PALETTE
N_COLOURS = 8


@dataclass
class Vehicles:
    """Every vehicle of an episode; moving ones drive straight at constant speed.

    pos0: (V, 2) centre at t = 0; yaw: (V,) heading from +x (rad); speed: (V,) m/s;
    size: (V, 3) length, width, height; colour: (V,) palette index; parked: (V,) bool.
    """

    pos0: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    size: np.ndarray
    colour: np.ndarray
    parked: np.ndarray

    def __len__(self) -> int:
        return len(self.yaw)

    @property
    def velocity(self) -> np.ndarray:
        """(V, 2) world velocity, m/s."""
        return self.speed[:, None] * np.stack([np.cos(self.yaw), np.sin(self.yaw)], -1)

    def position(self, t: float) -> np.ndarray:
        """(V, 2) centres at time t, s."""
        return self.pos0 + self.velocity * t


@dataclass
class World:
    """An episode: static scatterers, reflecting/occluding walls, vehicles, and who is Ego/CAV."""

    road: str
    lanes: int
    static_pts: np.ndarray          # (S, 3) world scatterers
    static_kind: np.ndarray         # (S,) GUARDRAIL / FACADE / POLE
    walls_a: np.ndarray             # (W, 2) wall segment starts
    walls_b: np.ndarray             # (W, 2) wall segment ends
    wall_occludes: np.ndarray       # (W,) bool: facades block, guardrails only reflect
    vehicles: Vehicles
    ego: int
    cav: int
    relation: str                   # same / opposite / perpendicular
    meta: dict = field(default_factory=dict)


def _lane_centres(lanes: int) -> np.ndarray:
    return (np.arange(lanes) - (lanes - 1) / 2) * LANE_W


def _line_points(rng, a, b, spacing, jitter, z_lo, z_hi):
    length = float(np.hypot(*(np.asarray(b) - a)))
    n = max(int(length / spacing), 1)
    s = (np.arange(n) + 0.5) / n + rng.normal(0, jitter / max(length, 1e-6), n)
    xy = np.asarray(a) + np.clip(s, 0, 1)[:, None] * (np.asarray(b) - np.asarray(a))
    return np.column_stack([xy, rng.uniform(z_lo, z_hi, n)])


class _Builder:
    """Accumulates structures for one road layout."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.pts: list[np.ndarray] = []
        self.kind: list[np.ndarray] = []
        self.wa: list = []
        self.wb: list = []
        self.occ: list = []

    def guardrail(self, a, b) -> None:
        p = _line_points(self.rng, a, b, 0.6, 0.05, 0.4, 0.7)
        self.pts.append(p)
        self.kind.append(np.full(len(p), GUARDRAIL))
        self.wa.append(a)
        self.wb.append(b)
        self.occ.append(False)

    def facade(self, a, b) -> None:
        p = _line_points(self.rng, a, b, 0.7, 0.3, 0.2, 2.5)
        corners = np.array([[*a, 1.0], [*b, 1.0]])
        self.pts.append(np.vstack([p, corners, corners]))
        self.kind.append(np.full(len(p) + 4, FACADE))
        self.wa.append(a)
        self.wb.append(b)
        self.occ.append(True)

    def pole(self, xy) -> None:
        self.pts.append(np.array([[xy[0], xy[1], 0.6]]))
        self.kind.append(np.array([POLE]))

    def buildings_along(self, x: float, y0: float, y1: float, side: int) -> None:
        """Facades parallel to y at lateral offset x (side = -1 left of road, +1 right)."""
        y = y0
        while y < y1:
            length = self.rng.uniform(15, 45)
            end = min(y + length, y1)
            if end - y > 4:
                self.facade((x, y), (x, end))
                depth = self.rng.uniform(8, 20) * side
                self.facade((x, y), (x + depth, y))
                self.facade((x, end), (x + depth, end))
            y = end + self.rng.uniform(3, 12)

    def roadside(self, half_w: float, y0: float, y1: float, urban: bool, pole_pitch: float) -> None:
        """Both sides of a road along y from y0 to y1 (in the road's own frame)."""
        rng = self.rng
        for side in (-1, 1):
            if urban:
                self.buildings_along(side * (half_w + rng.uniform(3, 8)), y0, y1, side)
            else:
                self.guardrail((side * (half_w + 0.6), y0), (side * (half_w + 0.6), y1))
                if rng.random() < 0.5:
                    self.buildings_along(side * (half_w + rng.uniform(8, 25)), y0, y1, side)
            # vegetation, signs, curbs: irregular stationary clutter along the roadside
            n_veg = int((y1 - y0) / 0.7)
            veg = np.column_stack([side * (half_w + rng.uniform(1.0, 14.0, n_veg)), rng.uniform(y0, y1, n_veg),
                                   rng.uniform(0.1, 1.5, n_veg)])
            self.pts.append(veg)
            self.kind.append(np.full(n_veg, VEGETATION))
            ys = np.arange(y0 + pole_pitch / 2, y1, pole_pitch)
            for yy in ys:
                self.pole((side * (half_w + 1.2), yy))

    def result(self):
        pts = np.vstack(self.pts) if self.pts else np.zeros((0, 3))
        kind = np.concatenate(self.kind) if self.kind else np.zeros(0, int)
        wa = np.array(self.wa, float).reshape(-1, 2)
        wb = np.array(self.wb, float).reshape(-1, 2)
        return pts, kind, wa, wb, np.array(self.occ, bool)


def _rotate_seg(pts: np.ndarray, extra: float = 0.0) -> np.ndarray:
    """Rotate layout-frame xy by +90 deg (a road along y becomes a road along x), and by
    `extra` rad more (an oblique junction)."""
    out = np.asarray(pts, float).copy()
    out[..., 0], out[..., 1] = -out[..., 1].copy(), out[..., 0].copy()
    return turned(out, extra) if extra else out


def build_world(rng: np.random.Generator, mode: str) -> World:
    """Draw one episode of the given mode ('easy', 'hard' or 'mixed')."""
    if mode == "mixed":
        mode = "easy" if rng.random() < 0.5 else "hard"
    if mode == "easy":
        road, lanes, relation = "straight", int(rng.integers(2, 5)), "same"
    else:
        road = str(rng.choice(["straight", "intersection", "t-junction"], p=[0.4, 0.35, 0.25]))
        lanes = int(rng.integers(2, 11))
        if road == "straight":
            relation = str(rng.choice(["same", "opposite"], p=[0.45, 0.55]))
        else:
            relation = str(rng.choice(["same", "opposite", "perpendicular"], p=[0.25, 0.3, 0.45]))
        if lanes < 2:
            lanes = 2
    two_way = mode == "hard"
    half_w = lanes * LANE_W / 2
    urban = road != "straight" or rng.random() < 0.4
    pole_pitch = float(rng.uniform(20, 35))
    b = _Builder(rng)
    gap = half_w + 10.0
    skew = _junction_skew(rng) if road != "straight" else 0.0
    if road == "straight":
        b.roadside(half_w, -ROAD_HALF_LEN, ROAD_HALF_LEN, urban, pole_pitch)
    else:
        b.roadside(half_w, -ROAD_HALF_LEN, -gap, urban, pole_pitch)
        b.roadside(half_w, gap, ROAD_HALF_LEN, urban, pole_pitch)
        sub = _Builder(rng)
        if road == "intersection":
            sub.roadside(half_w, -ROAD_HALF_LEN, -gap, urban, pole_pitch)
        else:  # T-junction: the cross road leaves to -x; the +x side is closed by facades
            b.buildings_along(half_w + rng.uniform(3, 8), -gap, gap, 1)
        sub.roadside(half_w, gap, ROAD_HALF_LEN, urban, pole_pitch)  # rotated: lies at x < -gap
        p, k, wa, wb, occ = sub.result()
        b.pts.append(np.column_stack([_rotate_seg(p[:, :2], skew), p[:, 2]]))
        b.kind.append(k)
        b.wa.extend(_rotate_seg(wa, skew))
        b.wb.extend(_rotate_seg(wb, skew))
        b.occ.extend(occ.tolist())
    static_pts, kind, wa, wb, occ = b.result()
    vehicles, ego, cav = _traffic(rng, mode, road, lanes, two_way, relation, half_w, urban)
    meta = {"mode": mode, "road": road, "lanes": lanes, "relation": relation, "urban": bool(urban)}
    stopped = _stop_one(rng, vehicles, ego, cav)
    if stopped:
        meta["stopped"] = stopped
    if skew:
        _skew_cross_traffic(vehicles, skew)
        meta["junction_deg"] = round(90.0 + float(np.degrees(skew)), 2)
    if other_vehicle_range() is not None:
        meta["other_vehicles"] = os.environ[TRAFFIC_ENV]
    return World(road=road, lanes=lanes, static_pts=static_pts, static_kind=kind,
                 walls_a=wa, walls_b=wb, wall_occludes=occ, vehicles=vehicles,
                 ego=ego, cav=cav, relation=relation, meta=meta)


def _colour(rng: np.random.Generator, n: int) -> np.ndarray:
    # white, silver, grey, black, blue, red, dark green, yellow/other
    return rng.choice(N_COLOURS, size=n, p=[0.22, 0.14, 0.1, 0.2, 0.1, 0.1, 0.07, 0.07])


def _size(rng: np.random.Generator, n: int) -> np.ndarray:
    kind = rng.random(n)
    length = np.where(kind < 0.85, rng.uniform(4.0, 5.0, n), rng.uniform(7.0, 12.0, n))
    width = np.where(kind < 0.85, rng.uniform(1.75, 2.0, n), rng.uniform(2.3, 2.55, n))
    height = np.where(kind < 0.85, rng.uniform(1.4, 1.8, n), rng.uniform(2.8, 3.6, n))
    return np.column_stack([length, width, height])


def _traffic(rng, mode, road, lanes, two_way, relation, half_w, urban):
    """Place Ego, CAV and the other vehicles on lanes without overlaps."""
    centres = _lane_centres(lanes)
    # lane directions on the main road (along +y): right half +y, left half -y when two-way
    main_dir = np.where(centres > 0, 1, -1) if two_way else np.ones(lanes, int)
    if two_way and lanes % 2 == 1:
        main_dir[lanes // 2] = 1
    pos, yaw, speed, parked = [], [], [], []

    def add(p, heading, v, park=False) -> bool:
        p = np.asarray(p, float)
        for q, h in zip(pos, yaw):
            if np.hypot(*(q - p)) < 7.5:
                return False
        pos.append(p)
        yaw.append(heading)
        speed.append(v)
        parked.append(park)
        return True

    fwd_lanes = np.flatnonzero(main_dir > 0)
    ego_lane = int(rng.choice(fwd_lanes))
    add((centres[ego_lane], rng.uniform(-60, -20) if road != "straight" else 0.0), np.pi / 2,
        rng.uniform(8, 20))
    ego_pos = pos[0]
    dist = rng.uniform(10, 60)
    placed = False
    for _ in range(100):
        if relation == "same":
            lane = int(rng.choice(fwd_lanes))
            dy = dist * rng.choice([-1, 1], p=[0.35, 0.65])
            dx = centres[lane] - ego_pos[0]
            if abs(dx) >= dist:
                continue
            dy = np.sign(dy) * np.sqrt(dist**2 - dx**2)
            placed = add((centres[lane], ego_pos[1] + dy), np.pi / 2, rng.uniform(8, 20))
        elif relation == "opposite":
            back = np.flatnonzero(main_dir < 0)
            lane = int(rng.choice(back))
            dx = centres[lane] - ego_pos[0]
            if abs(dx) >= dist:
                continue
            dy = np.sqrt(dist**2 - dx**2)
            placed = add((centres[lane], ego_pos[1] + dy), -np.pi / 2, rng.uniform(8, 20))
        else:  # perpendicular: CAV on the crossing road heading toward the junction
            lane = int(rng.integers(lanes))
            side = rng.choice([-1, 1]) if road == "intersection" else -1
            x = side * rng.uniform(half_w + 6, 50)
            heading = np.pi if side > 0 else 0.0
            y = abs(centres[lane]) * side
            if np.hypot(x - ego_pos[0], y - ego_pos[1]) > 60:
                continue
            placed = add((x, y), heading, rng.uniform(8, 20))
        if placed:
            break
        dist = rng.uniform(10, 60)
    if not placed:  # fall back to a same-direction CAV right ahead
        lane = int(rng.choice(fwd_lanes))
        add((centres[lane], ego_pos[1] + 25.0), np.pi / 2, rng.uniform(8, 20))
    dense = other_vehicle_range()
    if dense is not None:
        n_other = int(rng.integers(dense[0], dense[1] + 1))
    else:
        n_other = int(rng.integers(1, 5)) if mode == "easy" else int(rng.integers(6, 21))
    span = 90.0
    tries = 0
    while len(pos) < n_other + 2 and tries < max(500, 25 * n_other):
        tries += 1
        on_cross = road != "straight" and rng.random() < 0.35
        lane = int(rng.integers(lanes))
        v = rng.uniform(8, 20)
        if on_cross:
            side = rng.choice([-1, 1]) if road == "intersection" else -1
            x = side * rng.uniform(half_w + 4, span)
            d = rng.choice([-1, 1]) if two_way else -side
            y = -d * abs(centres[lane])
            add((x, y), 0.0 if d > 0 else np.pi, v)
        else:
            y = ego_pos[1] + rng.uniform(-40, span)
            d = main_dir[lane]
            add((centres[lane], y), np.pi / 2 if d > 0 else -np.pi / 2, v)
    # parked cars along the curb
    n_parked = int(rng.integers(2, 7)) if urban else int(rng.integers(0, 3))
    for _ in range(n_parked * 3):
        if sum(parked) >= n_parked:
            break
        side = rng.choice([-1, 1])
        add((side * (half_w + 1.3), ego_pos[1] + rng.uniform(-20, span)), np.pi / 2 + rng.normal(0, 0.03),
            0.0, park=True)
    n = len(pos)
    # nobody drives exactly along the lane: lane keeping wobble and lane changes (1.5 deg rms)
    heading_noise = rng.normal(0, np.radians(1.5), n)
    vehicles = Vehicles(pos0=np.array(pos), yaw=np.array(yaw) + heading_noise, speed=np.array(speed),
                        size=_size(rng, n), colour=_colour(rng, n), parked=np.array(parked))
    return vehicles, 0, 1


def other_vehicle_range() -> tuple[int, int] | None:
    """(LO, HI) other vehicles per episode when dense traffic is asked for (TRAFFIC_ENV), else None.

    Lanes hold a vehicle every 7.5 m at most, so very high counts saturate the road.
    """
    text = os.environ.get(TRAFFIC_ENV)
    return parse_range(text, TRAFFIC_ENV, 0, 1000, int) if text else None


def parse_range(text: str, key: str, low: float, high: float, kind: type = float) -> tuple:
    """'LO-HI' -> (LO, HI) of `kind` with low <= LO <= HI <= high; a broken value names `key`."""
    from mmatch.errors import ConfigError

    try:
        lo, hi = (kind(x) for x in str(text).split("-"))
    except ValueError:
        raise ConfigError(f"{key}: {text!r} is not LO-HI (two {'whole ' if kind is int else ''}numbers)") from None
    if not low <= lo <= hi <= high:
        raise ConfigError(f"{key}: {text!r} needs {low} <= LO <= HI <= {high}")
    return lo, hi


def junction_range() -> tuple[float, float] | None:
    """(LO, HI) angle in deg between the crossing roads of a junction (JUNCTION_ENV), else None (90)."""
    text = os.environ.get(JUNCTION_ENV)
    return parse_range(text, JUNCTION_ENV, 45, 135) if text else None


def _junction_skew(rng: np.random.Generator) -> float:
    """The cross road's turn away from the perpendicular (rad): 0 unless `junction_range()`
    asks for oblique junctions; drawn from a generator seeded by `rng`'s state without
    advancing it (as `_stop_one`), so 90-deg worlds are those of the same seed."""
    rng_deg = junction_range()
    if rng_deg is None:
        return 0.0
    return float(np.radians(_detached(rng, 2**61, 7).uniform(*rng_deg) - 90.0))


def _skew_cross_traffic(vehicles: Vehicles, skew: float) -> None:
    """Turn the vehicles on the cross road (those driving along x) about the junction by skew."""
    along_x = np.abs(np.sin(vehicles.yaw)) < np.sin(np.radians(20.0))
    vehicles.pos0[along_x] = turned(vehicles.pos0[along_x], skew)
    vehicles.yaw[along_x] += skew


def _detached(rng: np.random.Generator, modulus: int, offset: int = 0) -> np.random.Generator:
    """A generator seeded by `rng`'s state (modulo `modulus`, plus `offset`) without advancing
    it: draws for an opt-in situation leave the seed's world as it is."""
    return np.random.default_rng(int(rng.bit_generator.state["state"]["state"]) % modulus + offset)


def junction_override(degrees: tuple[float, float] | None) -> contextlib.AbstractContextManager[None]:
    """Junction angles drawn from LO-HI deg inside the block (and in worker processes started in it)."""
    return _environment(JUNCTION_ENV, None if degrees is None else f"{float(degrees[0])}-{float(degrees[1])}")


def stopped_share() -> float:
    """Share of episodes in which the Ego or the CAV stands still (STOPPED_ENV; 0 when unset)."""
    text = os.environ.get(STOPPED_ENV)
    if not text:
        return 0.0
    try:
        share = float(text)
    except ValueError:
        raise ValueError(f"{STOPPED_ENV}: {text!r} is not a number") from None
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"{STOPPED_ENV}: {text!r} is not a share in 0-1")
    return share


def _stop_one(rng: np.random.Generator, vehicles: Vehicles, ego: int, cav: int) -> str:
    """With probability `stopped_share()`, the Ego or the CAV (even odds) waits at 0-1 m/s (a
    light, a queue): its radar's velocity gives no road direction. Returns "ego", "cav" or "".

    The draws come from a generator seeded by `rng`'s state without advancing it, so the
    world is otherwise the one the same seed gives without stops (the scenario may still
    reject it where it kept the moving one, and draw another)."""
    share = stopped_share()
    if share <= 0:
        return ""
    sub = _detached(rng, 2**63)
    if sub.random() >= share:
        return ""
    who, name = (ego, "ego") if sub.random() < 0.5 else (cav, "cav")
    vehicles.speed[who] = sub.uniform(0.0, 1.0)
    return name


def stopped_override(share: float | None) -> contextlib.AbstractContextManager[None]:
    """Stop the Ego or the CAV in `share` of the episodes inside the block (and in worker
    processes started in it)."""
    return _environment(STOPPED_ENV, None if share is None else repr(float(share)))


def traffic_override(vehicles: tuple[int, int] | None) -> contextlib.AbstractContextManager[None]:
    """Draw LO-HI other vehicles per episode inside the block (and in worker processes started in it)."""
    return _environment(TRAFFIC_ENV, None if vehicles is None else f"{int(vehicles[0])}-{int(vehicles[1])}")


@contextlib.contextmanager
def _environment(name: str, value: str | None) -> Iterator[None]:
    """Environment variable `name` set to `value` inside the block (unchanged for None)."""
    old = os.environ.get(name)
    if value is not None:
        os.environ[name] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = old
