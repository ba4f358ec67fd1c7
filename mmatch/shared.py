"""The shared frame: what a CAV publishes each radar frame (DESIGN.md "Wire format").

All geometry is in the sender's radar frame (x right, y forward, z up; metres).
Vehicles are indexed 0..V-1; `vehicle_index` maps each vehicle point to its vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mmatch.numeric import median
from mmatch.types import DESCRIPTOR_DIM

# The shared frame's box corners are those of a pinhole camera of this focal length with its
# principal point at (0, 0): a box's height in these units times its depth / 1000 is metres.
CANONICAL_FOCAL_PX = 1000.0


def canonical_boxes(boxes: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Boxes (M, 6) u1, v1, u2, v2 (px of the camera with intrinsics K (3, 3)), score, depth ->
    the same boxes with corners in the canonical image: CANONICAL_FOCAL_PX x (u - cx) / fx and
    likewise v (skew ignored). Score and depth unchanged; float32."""
    b = np.array(boxes, np.float64).reshape(-1, 6)
    K = np.asarray(K, np.float64)
    b[:, [0, 2]] = CANONICAL_FOCAL_PX * (b[:, [0, 2]] - K[0, 2]) / K[0, 0]
    b[:, [1, 3]] = CANONICAL_FOCAL_PX * (b[:, [1, 3]] - K[1, 2]) / K[1, 1]
    return b.astype(np.float32)


# A frame's median detection score is read as at least this (`lifted_scores`).
TYPICAL_SCORE = 0.8


def lifted_scores(scores: np.ndarray, typical: float = TYPICAL_SCORE) -> np.ndarray:
    """(V,) float64 detection scores of one frame scaled up so that their median is at least
    `typical`: a detector calibrated lower overall keeps its ranking without every vehicle
    looking like a false detection (scores x 0.6 cost RM-net 3 points of pair F1 on perfect
    separation). Both sides read scores through this."""
    sc = np.asarray(scores, np.float64)
    if len(sc) == 0:
        return sc
    med = float(median(sc))
    return sc * (typical / med if 0 < med < typical else 1.0)


# The Ego reads a received background in one order whatever the sender's: lexicographic in the
# cells of this grid (x, then y, then z), the coordinates breaking ties. The CAV side's voxel
# sketch (cav/background.py, 0.5 m voxels) comes out in this order already.
BACKGROUND_ORDER_GRID_M = 0.5


# The most moving returns a frame shares beside its vehicles (`SharedFrame.moving`): our views
# hold 18 median, 47 at most (wide, stress and 30-40 vehicle scenes); a denser radar's are thinned.
MOVING_SKETCH_MAX = 64


@dataclass
class SharedFrame:
    """One CAV-side product, ready for the wire.

    sender: vehicle id (UTF-8, <= 64 bytes on the wire); seq: sequence number (uint64,
    strictly increasing per sender, across restarts too: receivers refuse a seq not above the last).
    stamp: capture time of the radar frame, s, shared clock.
    radar_height: sender's radar mounting height above the road, m.
    ego_velocity: float64 (2,) sender radar velocity over ground (vx, vy), m/s, its frame.
    vehicle_points: float32 (K, 5) x, y, z, doppler, snr of the moving-vehicle points.
    vehicle_index: int32 (K,) vehicle of each point, 0..V-1.
    vehicle_boxes: float32 (V, 6) the camera box of each vehicle (u1, v1, u2, v2, score, depth):
        corners in the canonical image (`canonical_boxes`: normalised image coordinates times
        CANONICAL_FOCAL_PX, so a receiver reads sizes and bearings without the sender's
        intrinsics), score 0-1, depth m.
    vehicle_box_index: int32 (V,) index of that box in the sender's detections.
    vehicle_centers: float32 (V, 2) x, y of each vehicle centre as the camera estimates it
        (box-centre bearing at the box depth); the radar's estimate is the centroid of the
        vehicle's points.
    vehicle_features: float32 (V, 32) appearance descriptor per vehicle.
    background: float32 (B, 3) x, y, z of the stationary-background sketch.
    moving: float32 (M, 2) x, y of the moving returns not shared as vehicle points (vehicles
        the camera did not box, out of its view or hidden from it): the moving sketch, at most
        MOVING_SKETCH_MAX (wire version 3; empty from a version-2 sender).
    """

    sender: str
    seq: int
    stamp: float
    radar_height: float
    ego_velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    vehicle_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 5), np.float32))
    vehicle_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    vehicle_boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), np.float32))
    vehicle_box_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    vehicle_centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    vehicle_features: np.ndarray = field(
        default_factory=lambda: np.zeros((0, DESCRIPTOR_DIM), np.float32))
    background: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    moving: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))

    @property
    def num_vehicles(self) -> int:
        return len(self.vehicle_boxes)

    def points_of(self, v: int) -> np.ndarray:
        """The (k, 5) points of vehicle v."""
        return self.vehicle_points[self.vehicle_index == v]


def with_canonical_background(frame: SharedFrame) -> SharedFrame:
    """The frame with its background points in the canonical order (BACKGROUND_ORDER_GRID_M):
    the frame itself when they are in it already, else a copy. Subsets of the background (the
    matcher's and the aligner's) then do not depend on the order a sender lists it in."""
    bg = np.asarray(frame.background)
    if len(bg) < 2:
        return frame
    cells = np.floor(bg[:, :3] / BACKGROUND_ORDER_GRID_M)
    order = np.lexsort((bg[:, 2], bg[:, 1], bg[:, 0], cells[:, 2], cells[:, 1], cells[:, 0]))
    if np.array_equal(order, np.arange(len(bg))):
        return frame
    return replace(frame, background=bg[order])
