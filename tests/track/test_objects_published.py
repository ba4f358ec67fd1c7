"""Object tracks as the vehicle service publishes them: track ids as the objects' 5th column, the
tracks with velocity and covariance in the fused message, Foxglove boxes turned along them."""

from __future__ import annotations

import json
import math

import numpy as np

from mmatch.codec import decode, encode
from mmatch.ego.track.objects import ObjectTracker
from mmatch.edge import config, logschema
from mmatch.edge.logschema import SensorFrame
from mmatch.edge.node import Node, dumps
from mmatch.edge.pipeline import Pipeline
from mmatch.edge.sources.base import default_camera
from mmatch.fusion import FusionResult
from mmatch.shared import SharedFrame


def process_view(points, boxes, features, camera, radar_height, stamp, *, sender="cav", seq=0):
    """A stand-in CAV side: one vehicle per point row, its centre as the camera would give it."""
    c = np.asarray(points, np.float32)[:, :2]
    V = len(c)
    return SharedFrame(sender=sender, seq=seq, stamp=stamp, radar_height=radar_height, vehicle_centers=c.copy(),
                       vehicle_boxes=np.zeros((V, 6), np.float32), vehicle_box_index=np.arange(V, dtype=np.int32),
                       vehicle_features=np.zeros((V, 32), np.float32)), {}


def fuse(own, other):
    """Identity transform, own vehicle 0 paired with the CAV's vehicle 0 (as fusion.merge_objects lays them out)."""
    a = np.c_[own.vehicle_centers, np.zeros(own.num_vehicles), np.arange(own.num_vehicles)]
    if other is None:
        return FusionResult("single", objects=a.astype(np.float32))
    a[0, 2] = 2
    b = np.c_[other.vehicle_centers, np.ones(other.num_vehicles), np.arange(other.num_vehicles)][1:]
    return FusionResult("fused", "", np.eye(4), np.array([[0, 0]], np.int32), np.r_[a, b].astype(np.float32))


def _cfg():
    return config.from_dict({"vehicle": {"id": "ego1", "role": "ego"}, "ego": {"cavs": ["cav1"]}})


def _cars(t: float) -> np.ndarray:
    """Two cars driving on at 5 m/s (their centres as the fake CAV side reads points)."""
    return np.array([[-3.0, 20.0 + 5 * t, 0, 0, 0], [3.0, 40.0 + 5 * t, 0, 0, 0]], np.float32)


def test_fused_objects_carry_track_ids_and_tracks():
    tracker = ObjectTracker()

    def track_objects(own, fused):
        return tracker.step(own, [(o, r.T_ego_cav, None, r.pairs) for o, r in fused])

    published = []
    node = Node(_cfg(), Pipeline(process_view, encode, decode, fuse, track_objects), default_camera(), 0.7,
                publish=lambda k, d: published.append(json.loads(d)))
    rows = []
    for k in range(12):
        t = 100.0 + 0.05 * k
        sf, _ = process_view(_cars(t - 100.0), None, None, None, 1.0, t + 0.01, sender="cav1", seq=k + 1)
        node.on_shared("cav1", encode(sf))
        msg = node.process(SensorFrame(seq=k + 1, stamp=t, points=_cars(t - 100.0),
                                       boxes=np.zeros((0, 6), np.float32), features=np.zeros((0, 32), np.float32)))
        rows.append(np.array(msg["objects"]))
    assert all(r.shape[1] == 5 for r in rows)
    own_ids = {tuple(r[r[:, 2] != 1][:, 4].astype(int)) for r in rows}
    assert len(own_ids) == 1 and -1 not in next(iter(own_ids))            # the same two ids every frame
    # the fake pairs own vehicle 0 with the CAV's vehicle 0: one object; the CAV's second car is
    # the own second car seen again, so it carries that track's id too
    last = rows[-1]
    assert sorted(last[last[:, 2] == 1][:, 4].astype(int)) == [max(next(iter(own_ids)))]
    msg = published[-1]
    tracks = {t["id"]: t for t in msg["tracks"]}
    assert set(next(iter(own_ids))) <= set(tracks)
    for t in tracks.values():
        assert np.array(t["covariance"]).shape == (4, 4) and t["updates"] >= 2 and t["coasting_s"] == 0.0
    assert dumps(msg)                                                      # strict JSON


def _scene(msg: dict):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    (build,) = [b for topic, b in logschema.fused_records(msg, 1.0) if topic == logschema.FUSED_OBJECTS]
    return SceneUpdate.FromString(build())


def test_foxglove_boxes_of_moving_tracks_turn_along_their_velocity():
    msg = {"vehicle": "ego1", "seq": 1, "stamp": 5.0, "cavs": [],
           "objects": [[1.0, 20.0, 0, 0, 7], [-3.0, 30.0, 2, 1, 8], [-3.2, 30.5, 0, 2, 8], [5.0, 9.0, 0, 3, -1],
                       [9.0, 50.0, 1, 0, 9], [9.5, 50.2, 1, 1, 9]],       # 9: a young track, not published
           "tracks": [{"id": 7, "x": 1.0, "y": 20.0, "vx": -10.0, "vy": 0.0},
                      {"id": 8, "x": -3.0, "y": 30.0, "vx": 0.2, "vy": 0.3}]}
    update = _scene(msg)
    by_id = {e.id: e for e in update.entities}
    assert set(by_id) == {"track/7", "track/8", "own/2", "own/3", "track/9", "other/1"}   # second detections: own boxes
    o = by_id["track/7"].cubes[0].pose.orientation                        # moving along -x: length turned onto x
    yaw = 2 * math.atan2(o.z, o.w)
    assert math.isclose(abs(math.cos(yaw)), 0.0, abs_tol=1e-9) and len(by_id["track/7"].arrows) == 1
    a = by_id["track/7"].arrows[0].pose.orientation
    assert math.isclose(2 * math.atan2(a.z, a.w) % (2 * math.pi), math.pi, abs_tol=1e-9)
    assert by_id["track/8"].cubes[0].pose.orientation.w == 1.0 and not by_id["track/8"].arrows   # too slow
    meta = {kv.key: kv.value for kv in by_id["track/7"].metadata}
    assert meta["track"] == "7" and float(meta["vx"]) == -10.0
