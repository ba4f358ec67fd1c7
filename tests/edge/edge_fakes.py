"""A stand-in pipeline with the contract's signatures, for testing the loop logic alone
(fake CAV processing and fusion, the real wire codec)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mmatch.codec import decode, encode
from mmatch.edge.pipeline import Pipeline
from mmatch.shared import SharedFrame


def process_view(points, boxes, features, camera, radar_height, stamp, *, sender="cav", seq=0, config=None):
    centers = np.asarray(points, np.float32)[:, :2][:3]
    return SharedFrame(sender=sender, seq=seq, stamp=stamp, radar_height=radar_height,
                       vehicle_centers=centers.copy(),
                       vehicle_boxes=np.zeros((len(centers), 6), np.float32),
                       vehicle_box_index=np.arange(len(centers), dtype=np.int32),
                       vehicle_features=np.zeros((len(centers), 32), np.float32)), {"egomotion": 0.1}


@dataclass
class FakeResult:
    status: str
    reason: str = ""
    T_ego_cav: np.ndarray | None = None
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    objects: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    timings: dict = field(default_factory=dict)


def fuse(own, other, config=None):
    own_obj = np.c_[own.vehicle_centers, np.zeros(len(own.vehicle_centers)), np.arange(len(own.vehicle_centers))]
    if other is None:
        return FakeResult("single", "no CAV frame", objects=own_obj.astype(np.float32))
    T = np.eye(4)
    T[0, 3] = other.stamp - own.stamp  # encodes which frame was used
    oth = np.c_[other.vehicle_centers, np.ones(len(other.vehicle_centers)), np.arange(len(other.vehicle_centers))]
    return FakeResult("fused", "", T, np.array([[0, 0]], np.int32), np.r_[own_obj, oth].astype(np.float32))


FAKE = Pipeline(process_view=process_view, encode=encode, decode=decode, fuse=fuse)  # the real codec
