"""Where each shared vehicle is, with how well each view knows it: centres and 2x2 covariances.

A view fixes a vehicle's bearing well (radar azimuth, or the camera box) and its range
poorly: the radar sees only the faces turned to it, so the true centre lies some unknown
distance beyond the point centroid (half a car, or half a bus), and a vehicle without
radar points has only the camera's monocular depth (5-15 % error). Each centre is
therefore an ellipse stretched along the line of sight. Two views of the same vehicle
from different directions cross their ellipses at the vehicle, which is what matching
and alignment with these covariances exploit; isotropic distances either reject true
pairs seen end-on from both sides or accept everything nearby.

A vehicle with points has a second estimate: the camera's (box bearing at the monocular
depth, `SharedFrame.vehicle_centers`). The frustum sometimes hands a box the returns of
another vehicle or of the background behind it; then only the camera's estimate is
right. Distances take the better of the two, the camera's at a small penalty.

Frames: the sender's radar frame (x right, y forward), metres.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from mmatch.ego.base import far_side_centres, point_counts
from mmatch.ego.memo import memo, shared_block
from mmatch.numeric import lengths
from mmatch.shared import SharedFrame


@dataclass(frozen=True)
class ObservationModel:
    """Standard deviations of a shared vehicle centre, along and across the line of sight.

    along_points_m: a vehicle with radar points, along the ray (unknown vehicle length), m.
    along_depth_rel / along_depth_m: a vehicle without points (camera depth), relative + fixed.
    across_m / across_rad: across the ray, fixed (vehicle width) + angular (bearing noise).
    camera_penalty: squared Mahalanobis units added when a vehicle with points is placed by
        its camera estimate instead. 4 (was 2) since the CAV side's context stage and the
        per-vehicle far-side shift: wrong returns are rarer and the radar estimate better, and
        the camera's depth (5-45 % off on wide physics) won pairings it should not (chosen on
        wide hard seeds 1, 3, 4 from 1 / 2 / 4 / 6 / 9: success 0.597 / 0.617 / 0.642 / 0.642 /
        0.640, pair F1 0.901 / 0.904 / 0.908 / 0.908 / 0.904).
    along_spread_free_m / along_spread_k: a vehicle whose returns spread in range by more than
        along_spread_free_m (a car's length) may hold another's returns (a vehicle the camera
        missed in the same columns, the background behind it): its along-ray deviation grows
        by along_spread_k times the excess, in quadrature (chosen on wide hard seeds 1, 3, 4,
        20-23 from k 0.5 / 1 / 2 and 3 / 5 / 7 m: success 0.661 -> 0.665, gross at coverage
        0.8 0.021 -> 0.017, pair F1 0.9215 -> 0.9210; held-out seeds 2, 5-9, 14-16 on average
        F1 +0.2 points, success +0.8, gross at coverage 0.8 2.5 -> 2.3 %).
    camera_bearing: a vehicle with points is placed on the camera's ray through its box
        (the box fixes the bearing better than a few radar returns: 0.26 m across against
        0.6 m at simulated ranges), at the range of its radar points: the two estimates
        are combined across the ray with their variances, camera_across_m + camera_across_rad
        x range for the camera; the camera is taken camera_back_m behind the radar (its
        exact place matters little: the ray passes through the camera's own centre estimate).
    """

    along_points_m: float = 1.5
    along_spread_free_m: float = 5.0
    along_spread_k: float = 1.0
    along_depth_rel: float = 0.12
    along_depth_m: float = 0.8
    across_m: float = 0.5
    across_rad: float = 0.015
    camera_penalty: float = 4.0
    camera_bearing: bool = True
    camera_across_m: float = 0.2
    camera_across_rad: float = 0.005
    camera_back_m: float = 1.8


@dataclass
class Observations:
    """One frame's vehicles, its radar frame: the best estimate and the camera's.

    centres (V, 2) m, cov (V, 2, 2) m^2: far-side-corrected point centroid, or the camera's
    estimate for a vehicle without points. cam_centres / cam_cov: the camera's estimate;
    cam_penalty (V,): squared Mahalanobis units for using it (0 where it is the only one).
    """

    centres: np.ndarray
    cov: np.ndarray
    cam_centres: np.ndarray
    cam_cov: np.ndarray
    cam_penalty: np.ndarray

    def subset(self, idx: np.ndarray) -> "Observations":
        """The vehicles `idx` only (same order)."""
        return Observations(self.centres[idx], self.cov[idx], self.cam_centres[idx], self.cam_cov[idx],
                            self.cam_penalty[idx])

    def modes(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """(centres, cov, penalty) of each estimate: [best, camera]."""
        return [(self.centres, self.cov, np.zeros(len(self.centres))),
                (self.cam_centres, self.cam_cov, self.cam_penalty)]


def _ray_cov(c: np.ndarray, along: np.ndarray, across_m: float, across_rad: float) -> np.ndarray:
    r = np.maximum(lengths(c), 1e-6)
    u = c / r[:, None]
    n = np.column_stack([-u[:, 1], u[:, 0]])
    across = across_m + across_rad * r
    return along[:, None, None] ** 2 * _outer(u) + across[:, None, None] ** 2 * _outer(n)


def _outer(u: np.ndarray) -> np.ndarray:
    """(V, 2, 2) outer products u u^T of vectors u (V, 2) (einsum's, at a third of its cost)."""
    return u[:, :, None] * u[:, None, :]


def _on_camera_ray(c: np.ndarray, cov: np.ndarray, cam: np.ndarray, has: np.ndarray,
                   model: ObservationModel, along: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radar centres of the vehicles with points moved towards their camera ray (see
    ObservationModel); along: (V,) their along-ray deviations, m."""
    c, cov = c.copy(), cov.copy()
    origin = np.array([0.0, -model.camera_back_m])
    d = cam[has] - origin
    d /= np.maximum(lengths(d), 1e-6)[:, None]
    n = np.column_stack([-d[:, 1], d[:, 0]])
    rel = c[has] - origin
    s_along, s_across = np.einsum("vi,vi->v", rel, d), np.einsum("vi,vi->v", rel, n)
    r = lengths(c[has])
    var_r = (model.across_m + model.across_rad * r) ** 2
    var_c = (model.camera_across_m + model.camera_across_rad * r) ** 2
    w = var_c / (var_c + var_r)                          # weight of the radar's across-ray offset
    c[has] = origin + d * s_along[:, None] + n * (w * s_across)[:, None]
    across = np.sqrt(var_r * var_c / (var_r + var_c))
    cov[has] = along[has, None, None] ** 2 * _outer(d) + across[:, None, None] ** 2 * _outer(n)
    return c, cov


@contextlib.contextmanager
def observations_shared() -> Iterator[None]:
    """Within this block `observe` computes each (frame, model) once, as do the other per-frame
    pair quantities of ego/memo.py: the matcher, the aligner and the confidence model of one
    fusion observe the same two frames (eight calls a frame pair otherwise; 1.5 ms of 20 at 40
    vehicles a view). The frames must not change inside the block; the shared arrays are
    read-only."""
    with shared_block():
        yield


def observe(frame: SharedFrame, model: ObservationModel = ObservationModel()) -> Observations:
    """Centres and line-of-sight covariances of a frame's vehicles (both estimates)."""
    return memo("observe", (frame,), lambda: _with_penalty(frame, model), model)


def _with_penalty(frame: SharedFrame, model: ObservationModel) -> Observations:
    """The geometry, shared by models that differ only in camera_penalty (the pose search's and
    the confidence model's), with this model's penalties."""
    geometry = _geometry_model(model)
    g = memo("observe_geometry", (frame,), lambda: _observe(frame, geometry), geometry)
    has = point_counts(frame) > 0
    return Observations(g.centres, g.cov, g.cam_centres, g.cam_cov, np.where(has, model.camera_penalty, 0.0))


@functools.lru_cache(maxsize=8)
def _geometry_model(model: ObservationModel) -> ObservationModel:
    """The model without camera penalty (kept: dataclasses.replace costs more than the lookup)."""
    return replace(model, camera_penalty=0.0)


def _range_excess(frame: SharedFrame, model: ObservationModel) -> np.ndarray:
    """(V,) how far each vehicle's returns spread in range beyond model.along_spread_free_m, m."""
    V = frame.num_vehicles
    pts = np.asarray(frame.vehicle_points, np.float64)
    if not len(pts) or model.along_spread_k == 0:
        return np.zeros(V)
    r = lengths(pts[:, :2])
    idx = np.asarray(frame.vehicle_index, np.intp)
    lo, hi = np.full(V, np.inf), np.full(V, -np.inf)
    np.minimum.at(lo, idx, r)
    np.maximum.at(hi, idx, r)
    spread = np.where(hi >= lo, hi - lo, 0.0)
    return np.maximum(spread - model.along_spread_free_m, 0.0)


def _observe(frame: SharedFrame, model: ObservationModel) -> Observations:
    c = far_side_centres(frame)
    V = len(c)
    if V == 0:
        z2, z22 = np.zeros((0, 2)), np.zeros((0, 2, 2))
        return Observations(z2, z22, z2, z22, np.zeros(0))
    has = point_counts(frame) > 0
    cam = np.asarray(frame.vehicle_centers, np.float64).reshape(-1, 2)
    cam_along = model.along_depth_m + model.along_depth_rel * lengths(cam)
    cam_cov = _ray_cov(cam, cam_along, model.across_m, model.across_rad)
    along_points = np.hypot(model.along_points_m, model.along_spread_k * _range_excess(frame, model))
    along = np.where(has, along_points, cam_along)
    cov = _ray_cov(c, along, model.across_m, model.across_rad)
    if model.camera_bearing and has.any():
        c, cov = _on_camera_ray(c, cov, cam, has, model, along)
    return Observations(centres=c, cov=cov, cam_centres=cam, cam_cov=cam_cov,
                        cam_penalty=np.where(has, model.camera_penalty, 0.0))


@dataclass(frozen=True)
class PairedObservations:
    """Both views' vehicles stacked for `mahalanobis` (best estimates, then camera ones), in
    float32: what every hypothesis of one frame pair shares (`paired`, once per pair)."""

    Va: int
    Vb: int
    ca: np.ndarray          # (2 Va, 2)
    Sa: np.ndarray          # (2 Va, 2, 2)
    cb: np.ndarray          # (2 Vb, 2)
    Sb: np.ndarray          # (2 Vb, 2, 2)
    pen: np.ndarray         # (2 Va, 2 Vb) camera penalties of each combination


def paired(A: Observations, B: Observations) -> PairedObservations:
    """The per-pair part of `mahalanobis`, for calling it on many hypotheses (once per fusion
    inside `observations_shared`)."""
    return memo("paired", (A, B), lambda: _paired(A, B))


def _paired(A: Observations, B: Observations) -> PairedObservations:
    f = np.float32
    Va, Vb = len(A.centres), len(B.centres)
    pen_a = np.concatenate([np.zeros(Va), A.cam_penalty])
    pen_b = np.concatenate([np.zeros(Vb), B.cam_penalty])
    return PairedObservations(Va, Vb, np.concatenate([A.centres, A.cam_centres]).astype(f),
                              np.concatenate([A.cov, A.cam_cov]).astype(f),
                              np.concatenate([B.centres, B.cam_centres]).astype(f),
                              np.concatenate([B.cov, B.cam_cov]).astype(f),
                              (pen_a[:, None] + pen_b[None, :]).astype(f))


def _maha_sq(ca, Sa, cb, Sb, R, t):
    """(Va, Vb, H) squared Mahalanobis distances, the hypotheses last; explicit 2x2 algebra
    (einsum is slow here), in float32 (half the memory traffic of these arrays; distances are
    gated at a few sigma, far above float32's resolution).

    Hypotheses last and the arithmetic in place: with a few vehicles a view the pair axes are
    short, so every broadcast over them would run numpy's inner loops a handful of elements
    at a time and every temporary would cost as much as computing it."""
    f = np.float32
    R, t = np.asarray(R, f), np.asarray(t, f)
    c, s = R[:, 0, 0], R[:, 1, 0]                                             # (H,)
    bx, by = cb[:, 0, None], cb[:, 1, None]                                   # (Vb, 1)
    btx, bty = c * bx - s * by + t[:, 0], s * bx + c * by + t[:, 1]           # (Vb, H)
    a, b, d = Sb[:, 0, 0, None], Sb[:, 0, 1, None], Sb[:, 1, 1, None]
    cc, ss, cs = c * c, s * s, c * s
    r00 = a * cc - 2 * b * cs + d * ss                                        # R Sb R^T, (Vb, H)
    r01 = (a - d) * cs + b * (cc - ss)
    r11 = a * ss + 2 * b * cs + d * cc
    s00 = Sa[:, None, None, 0, 0] + r00                                       # (Va, Vb, H)
    s01 = Sa[:, None, None, 0, 1] + r01
    s11 = Sa[:, None, None, 1, 1] + r11
    dx = ca[:, None, None, 0] - btx
    dy = ca[:, None, None, 1] - bty
    det = s00 * s11
    det -= s01 * s01
    np.maximum(det, f(1e-12), out=det)
    q = s11                                 # s11 dx dx - 2 s01 dx dy + s00 dy dy, left to right
    q *= dx
    q *= dx
    s01 *= 2
    s01 *= dx
    s01 *= dy
    q -= s01
    s00 *= dy
    s00 *= dy
    q += s00
    q /= det
    return q


def pair_major_mahalanobis(A: Observations | PairedObservations, B: Observations | None,
                           R: np.ndarray, t: np.ndarray, with_modes: bool = False):
    """`mahalanobis` with the hypotheses last: (Va, Vb, H) distances (and modes), for callers
    that reduce over the vehicles (a reduction over a short last axis is slow in numpy)."""
    P = A if isinstance(A, PairedObservations) else paired(A, B)
    return best_combination(combination_squares(P, R, t), P.Va, P.Vb, with_modes)


def combination_squares(P: PairedObservations, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(2 Va, 2 Vb, H) float32 squared Mahalanobis distances plus camera penalties of every
    combination of the two views' estimates under hypotheses R (H, 2, 2), t (H, 2): four
    (Va, Vb) blocks, own best / camera by other best / camera (`best_combination`)."""
    q = _maha_sq(P.ca, P.Sa, P.cb, P.Sb, R, t)
    q += P.pen[:, :, None]
    return q


def best_combination(q: np.ndarray, Va: int, Vb: int, with_modes: bool = False):
    """(Va, Vb, H) distances of the best combination of `combination_squares` q (left as it
    is), and with_modes the (Va, Vb, H) int8 combination (`mahalanobis`)."""
    # the four combinations are the four blocks of q; the best of them block by block (a
    # reduction over a combination axis costs twice as much)
    best = q[:Va, :Vb]
    mode = np.zeros(best.shape, np.int8) if with_modes else None
    for k, block in ((1, q[:Va, Vb:]), (2, q[Va:, :Vb]), (3, q[Va:, Vb:])):
        if with_modes:
            mode[block < best] = k           # strictly better: ties keep the lower mode (argmin's)
        best = np.minimum(best, block)
    np.maximum(best, 0.0, out=best)
    d = np.sqrt(best, out=best)
    return (d, mode) if with_modes else d   # mode: 2 * own mode + other mode


def modes_at(q: np.ndarray, Va: int, Vb: int, a: np.ndarray, b: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(k,) `best_combination`'s modes of own vehicles a (k,) and other vehicles b (k,) under
    hypotheses h (k,) only: for callers that need a few of them. q must be C-contiguous (it is
    as `combination_squares` makes it): the four blocks' entries are taken by flat index."""
    H = q.shape[2]
    cell = (a * (2 * Vb) + b) * H + h                                      # flat index in q
    own_cam, other_cam = Va * 2 * Vb * H, Vb * H
    return np.take(q, cell + np.array([[0], [other_cam], [own_cam], [own_cam + other_cam]])).argmin(axis=0)


def mahalanobis(A: Observations | PairedObservations, B: Observations | None, R: np.ndarray, t: np.ndarray,
                with_modes: bool = False):
    """(H, Va, Vb) Mahalanobis distance between own vehicles and other vehicles moved by (R, t).

    R: (H, 2, 2), t: (H, 2) hypotheses of the other -> own transform. The two covariances add
    (the other's rotated into the own frame); each pair takes the best combination of the
    two views' estimates (penalties added). with_modes also returns the (H, Va, Vb) index of
    that combination (0 best-best, 1 best-camera, 2 camera-best, 3 camera-camera).
    A may be `paired(A, B)` (B then None), computed once for many calls.
    """
    out = pair_major_mahalanobis(A, B, R, t, with_modes)
    if with_modes:
        return tuple(np.ascontiguousarray(x.transpose(2, 0, 1)) for x in out)
    return np.ascontiguousarray(out.transpose(2, 0, 1))
