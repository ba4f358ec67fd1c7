"""Fused object tracks: a constant-velocity filter per vehicle in the Ego radar frame, fed by both views.

State of a track at the Ego's capture stamp of the last frame: x = (px, py, vx, vy), the
vehicle's centre in the Ego radar frame (m) and its ground velocity in the Ego radar's axes
(m/s); P its 4x4 covariance. Between frames a track moves by its velocity and the Ego radar's
own motion (its Doppler-fitted velocity, the pose filter's yaw rate) is taken out, so the
state stays in the current Ego radar frame.

Each frame every vehicle of the own view and of every fused CAV view is a measurement:
- its centre: the nearest of its radar points plus `near_face_m` along their mean bearing (a
  radar sees the faces turned to it; the nearest return is steadier than the centroid), or
  the camera's centre (box bearing at box depth) for a vehicle without points; a CAV's mapped
  by T_ego_cav with the transform's (x, y, yaw) covariance carried into it. A CAV's vehicle is
  seen at the CAV's capture time: the measurement model moves the track by its velocity over
  the stamp difference, so the CAV's vehicles are compared at the Ego's capture time;
- its ground radial speed along its line of sight (ego/base.py `radial_ground_speeds`: the
  Doppler of its points plus the sender's own velocity). A vehicle two radars see gets two
  radial speeds along two lines of sight, which fix its 2-D velocity in one frame (the solve
  of ego/confidence.py `two_view_velocities`); over frames the centres add the rest.
Both have heavy tails (another vehicle's points, a ghost, a camera depth): an innovation
beyond `huber_k` sigmas weighs less (Huber), a radial speed far off is not used.

Association, sender by sender (own first), one-to-one (a track takes at most one view of each
radar): Hungarian on the negative log-likelihood of each view under each predicted track
(position and radial speed, gated), a young track costing more and the track of the own
vehicle the matcher paired a CAV vehicle with costing less. What is left: a second detection
of a vehicle that radar's view already went to keeps that id; then a wider gate for a track
no view of this radar took; the rest start tracks (a CAV vehicle paired with an own vehicle
that starts one joins it). So a vehicle keeps one id whether the own radar, the CAV's or
both see it. A track nothing updates coasts on its velocity and is dropped after `coast_s`
(a young one sooner); two tracks that became one vehicle keep the older id. Ids are never
reused.

Frames: the Ego radar frame (x right, y forward), metres, seconds, m/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from mmatch.ego.base import radial_ground_speeds
from mmatch.shared import SharedFrame

CHI2_2_999 = 13.82          # 99.9 % of chi-square, 2 dof
CHI2_2_99 = 9.21


@dataclass(frozen=True)
class ObjectTrackConfig:
    """Noise, gates and life of the object tracks (units in the names).

    accel_sigma_mps2: a vehicle's white acceleration (braking, lane changes, turns);
    radial_sigma_mps: a ground radial speed from one radar; radial_reject_mps: one farther than
    this from the track's (beyond the track's own uncertainty) is not used;
    near_face_m: centre beyond the nearest radar return; along_sigma_m / across_sigma_m /
    across_sigma_rad: a radar-based centre's error along / across the line of sight (a fixed
    and an angular share); box_depth_rel: a camera-only centre's depth error (share of range);
    huber_k: innovations beyond this many sigmas weigh less;
    yaw_rate_sigma: the Ego's yaw-rate uncertainty (rad/s); own_yaw_rate_sigma: the Fuser passes
    the pose filter's Ego yaw rate only when it is known this well (else 0); spawn_sigma_mps: a new track's
    velocity uncertainty before its radial speeds;
    loose_factor / loose_max_m: the wider gate (variance factor) and its distance cap;
    young_cost: extra cost of a track with fewer than confirm_hits updates; pair_bonus: less
    cost for the track of the own vehicle a CAV vehicle is paired with;
    coast_s / young_coast_s: a track no view updates is dropped after this (young: sooner);
    publish_coast_s: a coasting track is published this long;
    duplicate_m / duplicate_sigma_m / duplicate_mps: two tracks at most duplicate_m apart that
    agree within their covariances (plus duplicate_sigma_m: the pose error between the views)
    and in velocity are one vehicle; a second view of one radar within duplicate_m of (or in the
    gate of) the track its first view went to is a second detection of that vehicle."""

    accel_sigma_mps2: float = 1.5
    radial_sigma_mps: float = 0.15
    radial_reject_mps: float = 2.0
    near_face_m: float = 2.2
    along_sigma_m: float = 0.45
    across_sigma_m: float = 0.3
    across_sigma_rad: float = 0.008
    box_depth_rel: float = 0.2
    huber_k: float = 2.5
    yaw_rate_sigma: float = 0.02
    own_yaw_rate_sigma: float = 0.01
    spawn_sigma_mps: float = 6.0
    loose_factor: float = 9.0
    loose_max_m: float = 5.0
    young_cost: float = 2.0
    pair_bonus: float = 3.0
    confirm_hits: int = 3
    coast_s: float = 2.0
    young_coast_s: float = 0.3
    publish_coast_s: float = 0.5
    duplicate_m: float = 2.0
    duplicate_sigma_m: float = 0.8
    duplicate_mps: float = 2.0


@dataclass
class ObjectTrack:
    """One vehicle: id, state x (4,), covariance P (4, 4), update count, last update and first
    stamps (s), and which views updated it last (0 own, 1 other, 2 both)."""

    id: int
    x: np.ndarray
    P: np.ndarray
    hits: int
    last_update: float
    first_stamp: float
    source: int = 0


@dataclass
class ObjectFrame:
    """A frame's object tracking: the track id of every own vehicle (V_own,) and of every
    vehicle of each fused CAV view ({sender: (V,)}), -1 for none; the tracks to publish (updated
    this frame or coasting at most publish_coast_s, with at least two updates); the Ego stamp."""

    own_ids: np.ndarray
    other_ids: dict[str, np.ndarray]
    tracks: list[ObjectTrack] = field(default_factory=list)
    stamp: float = 0.0


@dataclass
class _View:
    """One vehicle's measurement: key (sender, vehicle index), centre z (2,) with covariance Rz
    (2, 2), capture-time offset dt (s, from the Ego's stamp), ground radial speed g along unit u
    (2,) (NaN: none)."""

    key: tuple[str, int]
    z: np.ndarray
    Rz: np.ndarray
    dt: float
    g: float
    u: np.ndarray

    @property
    def has_radial(self) -> bool:
        return bool(np.isfinite(self.g) and np.isfinite(self.u[0]) and np.isfinite(self.u[1]))


def _rot(phi: float) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s], [s, c]])


def centres(frame: SharedFrame, near_face_m: float = 2.2) -> tuple[np.ndarray, np.ndarray]:
    """(V, 2) vehicle centres in the sender's radar frame and (V,) whether each came from radar
    points: the nearest point's range plus near_face_m along the points' mean bearing, else the
    camera's centre (box bearing at box depth)."""
    V = frame.num_vehicles
    c = np.asarray(frame.vehicle_centers, float).reshape(-1, 2).copy()
    has = np.zeros(V, bool)
    if len(frame.vehicle_points) and V:
        idx = frame.vehicle_index
        p = frame.vehicle_points[:, :2].astype(float)
        r = np.hypot(p[:, 0], p[:, 1])
        near = np.full(V, np.inf)
        np.minimum.at(near, idx, r)
        s = np.zeros((V, 2))
        np.add.at(s, idx, p / np.maximum(r, 1e-6)[:, None])
        has = np.isfinite(near)
        u = s[has] / np.maximum(np.linalg.norm(s[has], axis=1, keepdims=True), 1e-9)
        c[has] = u * (near[has] + near_face_m)[:, None]
    return c, has


def _centre_cov(c: np.ndarray, has_points: bool, cfg: ObjectTrackConfig) -> np.ndarray:
    """(2, 2) covariance of a vehicle centre c (2,) in its sender's frame."""
    r = float(np.hypot(*c))
    u = c / max(r, 1e-6)
    along = cfg.along_sigma_m if has_points else max(cfg.along_sigma_m, cfg.box_depth_rel * r)
    across = np.hypot(cfg.across_sigma_m, cfg.across_sigma_rad * r)
    n = np.array([-u[1], u[0]])
    return along ** 2 * np.outer(u, u) + across ** 2 * np.outer(n, n)


def views_of(frame: SharedFrame, sender: str, T: np.ndarray | None, pose_cov: np.ndarray | None,
             dt: float, cfg: ObjectTrackConfig) -> list[_View]:
    """Every vehicle of `frame` as a measurement in the Ego radar frame (T: 4x4 T_ego_cav, None
    for the own frame; pose_cov: its (3, 3) x, y, yaw covariance, carried into the centres);
    dt: the frame's capture time minus the Ego's, s."""
    c, has = centres(frame, cfg.near_face_m)
    g, u = radial_ground_speeds(frame)
    R = np.eye(2) if T is None else np.asarray(T, float)[:2, :2]
    t = np.zeros(2) if T is None else np.asarray(T, float)[:2, 3]
    cov = np.asarray(pose_cov, float) if pose_cov is not None else None
    use_cov = T is not None and cov is not None and cov.shape == (3, 3) and bool(np.all(np.isfinite(cov)))
    out = []
    for k in range(frame.num_vehicles):
        Rc = R @ c[k]
        Rz = R @ _centre_cov(c[k], bool(has[k]), cfg) @ R.T
        if use_cov:
            J = np.array([[1.0, 0.0, -Rc[1]], [0.0, 1.0, Rc[0]]])
            Rz = Rz + J @ cov @ J.T
        uk = R @ u[k] if np.all(np.isfinite(u[k])) else np.full(2, np.nan)
        out.append(_View((sender, k), Rc + t, Rz, float(dt), float(g[k]), uk))
    return out


def _h_position(v: _View) -> np.ndarray:
    """(2, 4) the centre's model: the track moved over the view's capture-time offset."""
    H = np.zeros((2, 4))
    H[:, :2] = np.eye(2)
    H[:, 2:] = v.dt * np.eye(2)
    return H


def _h_radial(v: _View) -> np.ndarray | None:
    return np.array([0.0, 0.0, v.u[0], v.u[1]]) if v.has_radial else None


def _position_nll(tr: ObjectTrack, v: _View, factor: float = 1.0) -> tuple[float, float]:
    """(squared Mahalanobis distance of the view's centre from the track, log-determinant)."""
    H = _h_position(v)
    y = v.z - H @ tr.x
    S = H @ tr.P @ H.T + v.Rz * factor
    try:
        return float(y @ np.linalg.solve(S, y)), float(np.linalg.slogdet(S)[1])
    except np.linalg.LinAlgError:
        return float("inf"), 0.0


def _radial_ok(tr: ObjectTrack, v: _View, cfg: ObjectTrackConfig) -> tuple[bool, float]:
    """(whether the view's radial speed may update the track, its squared normalised innovation)."""
    h = _h_radial(v)
    if h is None:
        return False, 0.0
    sp = float(h @ tr.P @ h)
    nu = v.g - float(h @ tr.x)
    if abs(nu) > cfg.radial_reject_mps + 3.0 * np.sqrt(sp):
        return False, 0.0
    return True, nu ** 2 / (sp + cfg.radial_sigma_mps ** 2)


def _update(tr: ObjectTrack, views: list[tuple[_View, float]], cfg: ObjectTrackConfig,
            radial_gate: bool = True) -> None:
    """Kalman update of the track with its views (each with a noise factor), the centres and the
    radial speeds stacked; Huber weights against heavy tails."""
    zs, Hs, Rs = [], [], []
    for v, factor in views:
        H = _h_position(v)
        Rz = v.Rz * factor
        d2, _ = _position_nll(tr, v, factor)
        d = np.sqrt(max(d2, 0.0))
        zs.append(v.z)
        Hs.append(H)
        Rs.append(Rz * max(1.0, d / cfg.huber_k))
        h = _h_radial(v)
        if h is None:
            continue
        ok, k2 = _radial_ok(tr, v, cfg)
        if radial_gate and not ok:
            continue
        zs.append(np.array([v.g]))
        Hs.append(h[None])
        Rs.append(np.array([[cfg.radial_sigma_mps ** 2 * max(1.0, np.sqrt(k2) / cfg.huber_k)]]))
    if not zs:
        return
    z, H = np.concatenate(zs), np.vstack(Hs)
    Rm = np.zeros((len(z), len(z)))
    i = 0
    for r in Rs:
        Rm[i:i + len(r), i:i + len(r)] = r
        i += len(r)
    S = H @ tr.P @ H.T + Rm
    K = np.linalg.solve(S, H @ tr.P).T
    tr.x = tr.x + K @ (z - H @ tr.x)
    I_KH = np.eye(4) - K @ H
    tr.P = I_KH @ tr.P @ I_KH.T + K @ Rm @ K.T          # Joseph form


def _source(views: list[_View]) -> int:
    """0: own views only, 1: CAV views only, 2: both."""
    own = {v.key[0] == "" for v in views}
    return 2 if len(own) == 2 else (0 if True in own else 1)


def _same(a: ObjectTrack, b: ObjectTrack, cfg: ObjectTrackConfig) -> bool:
    """Whether two tracks are one vehicle (see ObjectTrackConfig.duplicate_*)."""
    d = a.x[:2] - b.x[:2]
    if d @ d >= cfg.duplicate_m ** 2 or np.sum((a.x[2:] - b.x[2:]) ** 2) >= cfg.duplicate_mps ** 2:
        return False
    S = a.P[:2, :2] + b.P[:2, :2] + np.eye(2) * cfg.duplicate_sigma_m ** 2
    return bool(d @ np.linalg.solve(S, d) < CHI2_2_99)


class ObjectTracker:
    """Tracks of the vehicles both views see and either sees; `step` once per Ego frame."""

    def __init__(self, config: ObjectTrackConfig = ObjectTrackConfig()) -> None:
        self.cfg = config
        self.tracks: list[ObjectTrack] = []
        self._next_id = 1
        self._stamp: float | None = None
        self._v_own = np.zeros(2)

    def reset(self) -> None:
        """Forget every track (ids start again at 1)."""
        self.tracks, self._stamp, self._next_id = [], None, 1

    def _predict(self, stamp: float, v_own: np.ndarray, yaw_rate: float) -> None:
        """Every track moved to `stamp` (s), in the Ego radar frame of that stamp."""
        dt = stamp - self._stamp if self._stamp is not None else 0.0
        if dt <= 0:
            return
        cfg = self.cfg
        v = (self._v_own + v_own) / 2                     # the Ego radar's velocity over the interval
        phi = yaw_rate * dt
        Rt = _rot(-phi)                                   # old frame -> new frame
        d = _rot(phi / 2) @ v * dt                        # the Ego radar's displacement (old frame)
        F = np.zeros((4, 4))
        F[:2, :2] = Rt
        F[:2, 2:] = Rt * dt
        F[2:, 2:] = Rt
        q = cfg.accel_sigma_mps2 ** 2
        Q = np.zeros((4, 4))
        Q[:2, :2] = np.eye(2) * q * dt ** 3 / 3
        Q[:2, 2:] = Q[2:, :2] = np.eye(2) * q * dt ** 2 / 2
        Q[2:, 2:] = np.eye(2) * q * dt
        for tr in self.tracks:
            n = np.array([-tr.x[1], tr.x[0]])             # the yaw-rate error moves it across its ray
            tr.x = F @ tr.x - np.r_[Rt @ d, 0.0, 0.0]
            tr.P = F @ tr.P @ F.T + Q
            tr.P[:2, :2] += (cfg.yaw_rate_sigma * dt) ** 2 * np.outer(n, n)

    def step(self, own: SharedFrame, fused: list[tuple[SharedFrame, np.ndarray, np.ndarray | None, np.ndarray]],
             yaw_rate: float = 0.0) -> ObjectFrame:
        """One Ego frame: `own` and, per fused CAV, (its frame, T_ego_cav 4x4, the (3, 3) pose
        covariance or None, pairs (P, 2) own vehicle -> its vehicle); yaw_rate: the Ego's (rad/s).

        Returns the track id of every vehicle of every view and the tracks to publish."""
        cfg = self.cfg
        stamp = float(own.stamp)
        v_own = np.asarray(own.ego_velocity, float).reshape(2)
        v_own = v_own if np.all(np.isfinite(v_own)) else np.zeros(2)
        if self._stamp is not None and stamp < self._stamp:       # time went back: a new drive
            self.reset()
        self._predict(stamp, v_own, float(yaw_rate) if np.isfinite(yaw_rate) else 0.0)
        self._stamp, self._v_own = stamp, v_own
        senders = [("", views_of(own, "", None, None, 0.0, cfg), {})]
        for other, T, cov, pairs in fused:
            vs = views_of(other, other.sender, T, cov, float(other.stamp) - stamp, cfg)
            pair_of = {int(j): int(i) for i, j in np.asarray(pairs, int).reshape(-1, 2)
                       if 0 <= i < own.num_vehicles and 0 <= j < len(vs)}
            senders.append((other.sender, vs, pair_of))
        n_t = len(self.tracks)
        members: dict[int, list[tuple[_View, float]]] = {}
        own_track: dict[int, int] = {}          # own vehicle -> track index (existing or new)
        ids: dict[tuple[str, int], int] = {}
        for name, vs, pair_of in senders:
            got, dups = self._assign(vs, list(range(n_t)), pair_of, own_track)
            for k, (b, factor) in got.items():
                members.setdefault(b, []).append((vs[k], factor))
                ids[vs[k].key] = self.tracks[b].id
                if name == "":
                    own_track[k] = b
            for k, b in dups.items():
                ids[vs[k].key] = self.tracks[b].id
        for b, views in members.items():
            tr = self.tracks[b]
            _update(tr, views, cfg)
            tr.hits += 1
            tr.last_update = stamp
            tr.source = _source([v for v, _ in views])
        new: dict[int, list[_View]] = {}
        for name, vs, pair_of in senders:
            for k, v in enumerate(vs):
                if v.key in ids:
                    continue
                i = pair_of.get(k)
                if name != "" and i is not None and own_track.get(i) in new:
                    b = own_track[i]
                    new[b].append(v)
                else:
                    b = len(self.tracks)
                    self.tracks.append(ObjectTrack(self._next_id, np.zeros(4), np.eye(4), 0, stamp, stamp))
                    self._next_id += 1
                    new[b] = [v]
                    if name == "":
                        own_track[k] = b
                ids[v.key] = self.tracks[b].id
        for b, views in new.items():
            self._start(self.tracks[b], views)
        merged = self._prune(stamp)
        ids = {key: merged.get(i, i) for key, i in ids.items()}
        own_ids = np.array([ids.get(("", k), -1) for k in range(own.num_vehicles)], np.int64)
        other_ids = {o.sender: np.array([ids.get((o.sender, k), -1) for k in range(o.num_vehicles)], np.int64)
                     for o, *_ in fused}
        live = [tr for tr in self.tracks if tr.hits >= 2 and stamp - tr.last_update <= cfg.publish_coast_s]
        return ObjectFrame(own_ids, other_ids, live, stamp)

    def _costs(self, views: list[_View], cols: list[int], factor: float) -> tuple[np.ndarray, np.ndarray]:
        """Costs (n, m) of views to the tracks `cols`: the negative log-likelihood of each centre
        and radial speed under each predicted track (inf outside the gate; in the wider gate only
        within loose_max_m), a young track costing more; and the squared Mahalanobis distances
        of the centres (n, m). Vectorised over views and tracks."""
        cfg = self.cfg
        x = np.array([self.tracks[b].x for b in cols]).reshape(-1, 4)
        P = np.array([self.tracks[b].P for b in cols]).reshape(-1, 4, 4)
        dt = np.array([v.dt for v in views])[:, None, None, None]
        z = np.array([v.z for v in views]).reshape(-1, 2)
        Rz = np.array([v.Rz for v in views]).reshape(-1, 2, 2) * factor
        # the centre's model H = [I, dt I]: H P H^T and H x for every view and track
        HPH = (P[None, :, :2, :2] + dt * (P[None, :, :2, 2:] + P[None, :, 2:, :2]) + dt ** 2 * P[None, :, 2:, 2:])
        S = HPH + Rz[:, None]
        y = z[:, None] - (x[None, :, :2] + dt[..., 0] * x[None, :, 2:])
        det = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]
        d2 = (S[..., 1, 1] * y[..., 0] ** 2 - 2 * S[..., 0, 1] * y[..., 0] * y[..., 1]
              + S[..., 0, 0] * y[..., 1] ** 2) / np.maximum(det, 1e-12)
        cost = d2 + np.log(np.maximum(det, 1e-12))
        ok = d2 < CHI2_2_999
        if factor > 1.0:
            ok &= np.hypot(y[..., 0], y[..., 1]) <= cfg.loose_max_m
        # radial speeds: agreeing ones add their squared innovation, far ones a fixed penalty
        g = np.array([v.g for v in views])
        u = np.array([v.u for v in views]).reshape(-1, 2)
        has = np.isfinite(g) & np.isfinite(u).all(axis=1)
        uu = np.where(has[:, None], u, 0.0)
        sp = np.einsum("na,mab,nb->nm", uu, P[:, 2:, 2:], uu)
        nu = np.where(has, g, 0.0)[:, None] - uu @ x[:, 2:].T
        near = np.abs(nu) <= cfg.radial_reject_mps + 3.0 * np.sqrt(sp)
        k2 = np.minimum(nu ** 2 / (sp + cfg.radial_sigma_mps ** 2), CHI2_2_99)
        cost += np.where(has[:, None], np.where(near, k2, CHI2_2_99), 0.0)
        hits = np.array([self.tracks[b].hits for b in cols])
        cost += np.where(hits < cfg.confirm_hits, cfg.young_cost, 0.0)[None]
        return np.where(ok, cost, np.inf), d2

    def _assign(self, views: list[_View], cols: list[int], pair_of: dict[int, int],
                own_track: dict[int, int]) -> tuple[dict[int, tuple[int, float]], dict[int, int]]:
        """One radar's views to tracks: ({view: (track index, noise factor)}, {view: track index of
        the vehicle it is a second detection of}). One-to-one in the gates first, then second
        detections, then the wider gate for the tracks left (noise widened as much)."""
        cfg = self.cfg
        out: dict[int, tuple[int, float]] = {}
        dups: dict[int, int] = {}
        for factor in (1.0, cfg.loose_factor):
            rows = [k for k in range(len(views)) if k not in out and k not in dups]
            free = [b for b in cols if b not in {t for t, _ in out.values()}]
            if rows and free:
                cost, d2 = self._costs([views[k] for k in rows], free, factor)
                for r, k in enumerate(rows):         # the track of the own vehicle it is paired with
                    partner = own_track.get(pair_of.get(k, -1), -1)
                    if partner in free:
                        cost[r, free.index(partner)] -= cfg.pair_bonus
                finite = np.isfinite(cost)
                if finite.any():
                    shifted = np.where(finite, cost - cost[finite].min() + 1.0, 1e9)
                    for r, c in zip(*linear_sum_assignment(shifted)):
                        if finite[r, c]:
                            out[rows[r]] = (free[c], factor)
            if factor == 1.0:                    # second detections of a vehicle a view went to
                mine = sorted({t for t, _ in out.values()})
                left = [k for k in range(len(views)) if k not in out]
                if mine and left:
                    _, d2 = self._costs([views[k] for k in left], mine, 1.0)
                    dist = np.array([[np.hypot(*(views[k].z - self.tracks[b].x[:2])) for b in mine] for k in left])
                    for r, k in enumerate(left):
                        near = (dist[r] < cfg.duplicate_m) | (d2[r] < CHI2_2_999)
                        if near.any():
                            dups[k] = mine[int(np.argmin(np.where(near, d2[r], np.inf)))]
        return out, dups

    def _start(self, tr: ObjectTrack, views: list[_View]) -> None:
        """A new track from its first views: a broad prior at the first centre, standing still,
        updated with every view (the radial speeds fix the velocity along their lines of sight)."""
        cfg = self.cfg
        tr.x = np.r_[views[0].z, 0.0, 0.0]
        tr.P = np.diag([100.0, 100.0, cfg.spawn_sigma_mps ** 2, cfg.spawn_sigma_mps ** 2])
        tr.hits, tr.source = 1, _source(views)
        _update(tr, [(v, 1.0) for v in views], cfg, radial_gate=False)

    def _prune(self, stamp: float) -> dict[int, int]:
        """Drop tracks that coasted too long; of two tracks that are one vehicle the older stays.
        Returns {id dropped: id it became}."""
        cfg = self.cfg
        keep = [tr for tr in self.tracks
                if stamp - tr.last_update <= (cfg.coast_s if tr.hits >= cfg.confirm_hits else cfg.young_coast_s)]
        keep.sort(key=lambda tr: (tr.first_stamp, tr.id))
        out: list[ObjectTrack] = []
        merged: dict[int, int] = {}
        for tr in keep:
            same = [o for o in out if _same(o, tr, cfg)]
            if same:
                merged[tr.id] = same[0].id
            else:
                out.append(tr)
        out.sort(key=lambda tr: tr.id)
        self.tracks = out
        return merged


def object_rows(rows: np.ndarray, tracked: ObjectFrame | None, sender: str) -> np.ndarray:
    """Fused object rows (O, 4) x, y, source, index (fusion.merge_objects) with a 5th column,
    each object's track id (-1: none), when objects are tracked (`tracked`; None: the rows as
    they are). Source 0 and 2 rows index the own vehicles, source 1 rows those of `sender`."""
    rows = np.asarray(rows, np.float64).reshape(-1, 4)
    if tracked is None:
        return rows
    ids = np.full(len(rows), -1.0)
    own, other = tracked.own_ids, tracked.other_ids.get(sender, np.zeros(0, np.int64))
    for k, (src, idx) in enumerate(rows[:, 2:4].astype(int)):
        table = other if src == 1 else own
        if 0 <= idx < len(table):
            ids[k] = table[idx]
    return np.column_stack([rows, ids])


def track_record(t: ObjectTrack, stamp: float) -> dict:
    """One object track as the fused message carries it (docs/formats.md; Ego radar frame, m,
    m/s, s): id, x, y, vx, vy, covariance (4x4), source, updates, age_s, coasting_s."""
    return {"id": int(t.id), "x": round(float(t.x[0]), 6), "y": round(float(t.x[1]), 6),
            "vx": round(float(t.x[2]), 6), "vy": round(float(t.x[3]), 6),
            "covariance": [[round(float(v), 9) for v in row] for row in np.asarray(t.P, float)],
            "source": int(t.source), "updates": int(t.hits), "age_s": round(float(stamp - t.first_stamp), 6),
            "coasting_s": round(float(stamp - t.last_update), 6)}
