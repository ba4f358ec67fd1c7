"""The cross-view graph RM-net reads: nodes, local edges and cross edges from two shared frames.

Nodes are the detected vehicles of both views (own = Ego, other = CAV). Each node carries
its appearance descriptor and radar summaries measured in its own view's radar frame
(x right, y forward, metres); local edges join every two vehicles of one view with their
relative geometry; cross edges join every own vehicle to every other vehicle and start at
zero inside the network (they hold what message passing learns about the pair).

No common frame exists before alignment, so nothing here depends on where the other
vehicle stands: every feature of a view is computed from that view alone (invariant by
construction). Local edges join each vehicle to its K nearest vehicles of the same view
(K = min(V - 1, K_MAX), at least 2: with two vehicles the one neighbour is listed twice,
which leaves means and maxima unchanged), held densely: features (V, K, EDGE_DIM) and
neighbour indices (V, K), so the network gathers but never scatters and exports to ONNX
exactly.

Node features (NODE_DIM = 48), in order:
  0-31  descriptor as its Hellinger embedding (sqrt of each H, S, V group, unit length per group)
  32    range of the vehicle centre / 50 m          33, 34  sin, cos of its azimuth atan2(x, y)
  35    log1p(radar point count) / 3                 36    has radar points (0/1)
  37    point extent along the line of sight / 3 m   38    extent across it / 3 m
  39    mean Doppler / 20 m/s                        40    ground speed along the line of sight / 20 m/s
  41    ground speed known (0/1)                     42    detection score (0-1), lifted (base.py)
  43    (camera depth - radar range) / 5 m, 0 without points
  44    box height in metres: canonical box height x depth / 1000 px (shared.py) / 3 m
  45    speed along the own heading / 20 m/s (ground speed over the cosine, 0 when the ray is
        near-perpendicular)     46  the same across the heading    47  own speed / 20 m/s
Local edge features (EDGE_DIM = 10), edge i -> j (j a neighbour of i) of one view:
  0  d_ij / d_max (d_max: the view's largest vehicle distance, >= 1 m)   1  d_ij / 50 m
  2, 3  sin, cos of the edge direction (p_j - p_i) in the view's frame   4  edge angle / pi
  5  log(r_j / r_i) (ranges >= 1 m)
  6, 7  sin, cos of the azimuth difference az_j - az_i: the well-defined replacement for
        log(theta_i / theta_j), which breaks at zero and negative azimuth
  8  wrapped azimuth difference / pi                                     9  descriptor distance (0-1)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.ego.base import (descriptor_distance, detection_scores, radial_ground_speeds,
                             unit_descriptor_groups)
from mmatch.ego.observations import Observations, observe
from mmatch.shared import CANONICAL_FOCAL_PX, SharedFrame
from mmatch.types import DESCRIPTOR_DIM

NODE_DIM = 48
EDGE_DIM = 10
RANGE_SCALE_M = 50.0
SPEED_SCALE_MPS = 20.0
MIN_COS = 0.35
K_MAX = 8


@dataclass
class ViewGraph:
    """One view's part of the graph: nodes (V, NODE_DIM) float32, local edges (V, K, EDGE_DIM)
    float32 to the neighbours (V, K) int64."""

    nodes: np.ndarray
    edges: np.ndarray
    neighbours: np.ndarray

    @property
    def num_nodes(self) -> int:
        return len(self.nodes)


@dataclass
class CrossGraph:
    """Both views; the cross edges are implicit: every (own i, other j), scored as a (Va, Vb) matrix."""

    own: ViewGraph
    other: ViewGraph
    obs_own: Observations
    obs_other: Observations


def hellinger_embedding(features: np.ndarray) -> np.ndarray:
    """(V, 32) descriptors -> (V, 32) sqrt histograms, unit length per H, S, V group."""
    x = np.asarray(features, np.float64).reshape(-1, DESCRIPTOR_DIM)
    return np.concatenate(unit_descriptor_groups(x), axis=1)


def _extents(frame: SharedFrame, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V,) point count, spread along and across each vehicle's line of sight (m), mean Doppler (m/s)."""
    V = frame.num_vehicles
    idx = frame.vehicle_index
    counts = np.bincount(idx, minlength=V)[:V].astype(float)
    along, across, dop = np.zeros(V), np.zeros(V), np.zeros(V)
    if len(idx) == 0:
        return counts, np.stack([along, across]), dop
    p = frame.vehicle_points[:, :2].astype(float)
    u = centres / np.maximum(np.linalg.norm(centres, axis=1, keepdims=True), 1e-6)
    n = np.column_stack([-u[:, 1], u[:, 0]])
    rel = p - centres[idx]
    a = np.einsum("ki,ki->k", rel, u[idx])
    c = np.einsum("ki,ki->k", rel, n[idx])
    has = counts > 0
    cnt = np.maximum(counts, 1)
    for vals, out in ((a, along), (c, across)):
        m1 = np.bincount(idx, weights=vals, minlength=V)[:V] / cnt
        m2 = np.bincount(idx, weights=vals * vals, minlength=V)[:V] / cnt
        out[has] = np.sqrt(np.maximum(m2 - m1 * m1, 0))[has]
    dop[has] = (np.bincount(idx, weights=frame.vehicle_points[:, 3].astype(float), minlength=V)[:V] / cnt)[has]
    return counts, np.stack([along, across]), dop


def node_features(frame: SharedFrame, centres: np.ndarray) -> np.ndarray:
    """(V, NODE_DIM) float32 node features of one view (see the module docstring); centres (V, 2) m."""
    V = frame.num_vehicles
    x = np.zeros((V, NODE_DIM))
    if V == 0:
        return x.astype(np.float32)
    x[:, :32] = hellinger_embedding(frame.vehicle_features)
    r = np.linalg.norm(centres, axis=1)
    az = np.arctan2(centres[:, 0], centres[:, 1])
    x[:, 32] = r / RANGE_SCALE_M
    x[:, 33], x[:, 34] = np.sin(az), np.cos(az)
    counts, ext, dop = _extents(frame, centres)
    has = counts > 0
    x[:, 35] = np.log1p(counts) / 3
    x[:, 36] = has
    x[:, 37], x[:, 38] = ext[0] / 3, ext[1] / 3
    x[:, 39] = dop / SPEED_SCALE_MPS
    g, u = radial_ground_speeds(frame)
    known = np.isfinite(g)
    x[:, 40] = np.where(known, g, 0) / SPEED_SCALE_MPS
    x[:, 41] = known
    boxes = np.asarray(frame.vehicle_boxes, np.float64).reshape(-1, 6)
    x[:, 42] = np.clip(detection_scores(frame), 0, 1)
    x[:, 43] = np.where(has, np.clip(boxes[:, 5] - r, -10, 10), 0) / 5
    x[:, 44] = np.clip((boxes[:, 3] - boxes[:, 1]) * boxes[:, 5] / CANONICAL_FOCAL_PX, 0, 10) / 3
    v = np.asarray(frame.ego_velocity, float)
    speed = float(np.linalg.norm(v)) if np.all(np.isfinite(v)) else 0.0
    x[:, 47] = speed / SPEED_SCALE_MPS
    if speed > 0.5 and known.any():
        e = v / speed
        for col, d in ((45, e), (46, np.array([-e[1], e[0]]))):
            cos = np.where(known, np.nan_to_num(u) @ d, 0)
            ok = known & (np.abs(cos) > MIN_COS)
            x[ok, col] = np.clip(g[ok] / cos[ok], -40, 40) / SPEED_SCALE_MPS
    return np.nan_to_num(x).astype(np.float32)


def neighbour_count(V: int) -> int:
    """K of a view of V vehicles (see the module docstring); 0 below two vehicles."""
    return 0 if V < 2 else max(2, min(V - 1, K_MAX))


def edge_features(frame: SharedFrame, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local edges of one view: features (V, K, EDGE_DIM) float32 and neighbours (V, K) int64.

    centres (V, 2) m in the view's radar frame; each vehicle's K nearest other vehicles.
    """
    V = len(centres)
    K = neighbour_count(V)
    if K == 0:
        return np.zeros((V, 0, EDGE_DIM), np.float32), np.zeros((V, 0), np.int64)
    diff = centres[None, :, :] - centres[:, None, :]                    # p_j - p_i, (V, V, 2)
    dist = np.linalg.norm(diff, axis=2)
    dmax = max(float(dist.max()), 1.0)
    order = np.argsort(np.where(np.eye(V, dtype=bool), np.inf, dist), axis=1, kind="stable")
    nbr = order[:, : min(K, V - 1)]
    if nbr.shape[1] < K:                                                # two vehicles: repeat the one
        nbr = np.repeat(nbr, K, axis=1)[:, :K]
    rows = np.arange(V)[:, None]
    d, dv = dist[rows, nbr], diff[rows, nbr]
    ang = np.arctan2(dv[..., 1], dv[..., 0])
    r = np.maximum(np.linalg.norm(centres, axis=1), 1.0)
    az = np.arctan2(centres[:, 0], centres[:, 1])
    daz = (az[nbr] - az[:, None] + np.pi) % (2 * np.pi) - np.pi
    e = np.zeros((V, K, EDGE_DIM))
    e[..., 0] = d / dmax
    e[..., 1] = d / RANGE_SCALE_M
    e[..., 2], e[..., 3] = np.sin(ang), np.cos(ang)
    e[..., 4] = ang / np.pi
    e[..., 5] = np.log(r[nbr] / r[:, None])
    e[..., 6], e[..., 7] = np.sin(daz), np.cos(daz)
    e[..., 8] = daz / np.pi
    e[..., 9] = descriptor_distance(frame.vehicle_features, frame.vehicle_features)[rows, nbr]
    return e.astype(np.float32), nbr.astype(np.int64)


def view_graph(frame: SharedFrame, obs: Observations | None = None) -> tuple[ViewGraph, Observations]:
    """One view's nodes and local edges, with the observations (centres, covariances) they came from."""
    obs = observe(frame) if obs is None else obs
    e, nbr = edge_features(frame, obs.centres)
    return ViewGraph(node_features(frame, obs.centres), e, nbr), obs


def build_graph(own: SharedFrame, other: SharedFrame) -> CrossGraph:
    """The cross-view graph of a frame pair (what the Ego has at run time)."""
    g_own, o_own = view_graph(own)
    g_other, o_other = view_graph(other)
    return CrossGraph(g_own, g_other, o_own, o_other)
