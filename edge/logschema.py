"""What the field log holds: topics, their MCAP schemas, and record encoders/decoders.

Everything but raw device bytes has a schema; what Foxglove can draw uses Foxglove's own
schemas (package `foxglove-schemas-protobuf`, protobuf encoding), each vehicle in its own
frame `<vehicle>/radar` (MMatch radar axes: x right, y forward, z up; docs/prerequisites.md):

| topic | schema (encoding) | content |
| --- | --- | --- |
| /raw/uart | none (x-ti-uart) | UART data-port bytes as read (raw device bytes; stop first when disk runs low) |
| /raw/dca1000 | none (x-dca1000-frame) | one raw ADC frame (raw device bytes) |
| /radar/points | foxglove.PointCloud | this vehicle's radar points per processed frame: x, y, z, doppler, snr |
| /vehicle/frame | mmatch.SensorFrame (json) | seq, stamps, camera detections + descriptors of each processed frame |
| /shared/tx | mmatch.SharedFrameWire (json) | each shared frame this vehicle published, its wire bytes (base64) |
| /shared/rx/<v> | mmatch.SharedFrameWire (json) | each shared frame received from vehicle <v> (what replay feeds back) |
| <shared>/points | foxglove.PointCloud | a shared frame's vehicle points in `<sender>/radar`: x, y, z, doppler, snr, vehicle |
| <shared>/background | foxglove.PointCloud | its stationary-background sketch: x, y, z |
| <shared>/vehicles | foxglove.SceneUpdate | its vehicles at the camera's centre estimates |
| /fused | mmatch.Fused (json) | the Ego's fusion result per frame (docs/formats.md) |
| /fused/objects | foxglove.SceneUpdate | fused objects in `<ego>/radar`, coloured by source; each CAV's radar as an arrow |
| /tf | foxglove.FrameTransforms | T_ego_cav of every fused CAV: parent `<ego>/radar`, child `<cav>/radar` |
| /tf/quality | mmatch.TransformQuality (json) | per CAV and frame: status, confidence, covariance (x, y, yaw) of that transform |
| /health | mmatch.Health (json) | rates and drops |

(<shared> is /shared/tx or /shared/rx/<v>.) Log times are the recorder's strictly
increasing clock (ns), so file order is the order in which the loop saw things; replaying
in that order reproduces the live pairing. Message timestamps are capture stamps.
"""

from __future__ import annotations

import base64
import functools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mmatch.errors import ParseError

RAW_UART = "/raw/uart"
RAW_DCA = "/raw/dca1000"
POINTS = "/radar/points"
FRAME = "/vehicle/frame"
SHARED_TX = "/shared/tx"
SHARED_RX_PREFIX = "/shared/rx/"
FUSED = "/fused"
FUSED_OBJECTS = "/fused/objects"
TF = "/tf"
TF_QUALITY = "/tf/quality"
HEALTH = "/health"
#: views of a shared frame, below its wire topic
SHARED_POINTS, SHARED_BACKGROUND, SHARED_VEHICLES = "/points", "/background", "/vehicles"

RAW_TOPICS = (RAW_UART, RAW_DCA)
POINT_FIELDS = ("x", "y", "z", "doppler", "snr")
SHARED_POINT_FIELDS = (*POINT_FIELDS, "vehicle")
FLOAT32 = 7  # foxglove.PackedElementField.NumericType.FLOAT32

#: nominal vehicle box (width along x, length along y, height), m: the size of a marker at an
#: object's centre, aligned with the radar axes unless the object's track moves at least
#: MIN_HEADING_MPS (m/s): then it is turned along the track's velocity
VEHICLE_BOX_M = (1.8, 4.5, 1.5)
MIN_HEADING_MPS = 1.0
#: colours (r, g, b, a) of fused objects by source: 0 own, 1 other vehicle, 2 seen by both
SOURCE_COLOURS = {0: (0.20, 0.45, 1.00, 0.6), 1: (1.00, 0.55, 0.10, 0.6), 2: (0.20, 0.80, 0.30, 0.7)}
SOURCE_NAMES = {0: "own", 1: "other", 2: "both"}


def radar_frame(vehicle: str) -> str:
    """The Foxglove / TF frame id of a vehicle's radar."""
    return f"{vehicle}/radar"


# --------------------------------------------------------------------------- schemas

def _json_schema(title: str, properties: dict | None = None) -> bytes:
    return json.dumps({"title": title, "type": "object", "properties": properties or {}}).encode()


_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_B64 = {"type": "string", "contentEncoding": "base64"}
JSON_SCHEMAS: dict[str, bytes] = {
    "mmatch.SensorFrame": _json_schema("mmatch.SensorFrame", {
        "seq": {"type": "integer"}, "stamp": {"type": "number"}, "stamp_ns": {"type": "integer"},
        "host_time": {"type": "number"}, "frame_number": {"type": "integer"},
        "camera_stamp": {"type": ["number", "null"]}, "boxes": _B64, "features": _B64,
        "num_points": {"type": "integer"}}),
    "mmatch.SharedFrameWire": _json_schema("mmatch.SharedFrameWire", {
        "timestamp": _TIME, "sender": {"type": "string"}, "seq": {"type": "integer"},
        "stamp": {"type": "number"}, "data": _B64}),
    # the fused and health messages are documented in docs/formats.md; their schema stays an
    # open object (both grow with the features that fill them)
    "mmatch.Fused": json.dumps({"type": "object"}).encode(),
    "mmatch.TransformQuality": _json_schema("mmatch.TransformQuality", {
        "timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
        "status": {"type": "string"}, "reason": {"type": "string"},
        "confidence": {"type": ["number", "null"]},
        "covariance": {"type": ["array", "null"], "items": {"type": "number"},
                       "description": "3x3 row-major, (x m, y m, yaw rad) in the parent frame"}}),
    "mmatch.Health": json.dumps({"type": "object"}).encode(),
}


@functools.cache
def _foxglove(name: str) -> Any:
    """The foxglove_schemas_protobuf message class `name` (e.g. "PointCloud")."""
    import importlib

    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)


@functools.cache
def _descriptor_set(name: str) -> bytes:
    """The serialized FileDescriptorSet of a Foxglove message and everything it imports (the
    MCAP schema data of the protobuf profile)."""
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: Any) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        fd.CopyToProto(fds.file.add())

    add(_foxglove(name).DESCRIPTOR.file)
    return fds.SerializeToString()


RAW_SCHEMAS = {RAW_UART: "x-ti-uart", RAW_DCA: "x-dca1000-frame"}
_EXACT = {POINTS: "PointCloud", FRAME: "mmatch.SensorFrame", SHARED_TX: "mmatch.SharedFrameWire",
          FUSED: "mmatch.Fused", FUSED_OBJECTS: "SceneUpdate", TF: "FrameTransforms",
          TF_QUALITY: "mmatch.TransformQuality", HEALTH: "mmatch.Health"}
_VIEWS = {SHARED_POINTS: "PointCloud", SHARED_BACKGROUND: "PointCloud", SHARED_VEHICLES: "SceneUpdate"}


def parse_shared_topic(topic: str) -> tuple[str, str, str] | None:
    """("tx" | "rx", vehicle ("" for tx), view ("" for the wire record)) of a shared topic."""
    if topic == SHARED_TX or (topic.startswith(SHARED_TX + "/") and topic[len(SHARED_TX):] in _VIEWS):
        return "tx", "", topic[len(SHARED_TX):]
    if topic.startswith(SHARED_RX_PREFIX):
        vehicle, _, view = topic[len(SHARED_RX_PREFIX):].partition("/")
        view = f"/{view}" if view else ""
        if vehicle and (not view or view in _VIEWS):
            return "rx", vehicle, view
    return None


def _kind(topic: str) -> str:
    if topic in _EXACT:
        return _EXACT[topic]
    shared = parse_shared_topic(topic)
    if shared is None:
        raise ValueError(f"unknown log topic {topic!r}")
    return _VIEWS[shared[2]] if shared[2] else "mmatch.SharedFrameWire"


def schema_for(topic: str) -> tuple[str, str, bytes, str]:
    """(schema name, schema encoding, schema data, message encoding) of a topic; raw device
    bytes alone have no schema."""
    if topic in RAW_SCHEMAS:
        return (f"mmatch.Raw{'Uart' if topic == RAW_UART else 'Dca1000'}", "", b"", RAW_SCHEMAS[topic])
    kind = _kind(topic)
    if kind.startswith("mmatch."):
        return kind, "jsonschema", JSON_SCHEMAS[kind], "json"
    return f"foxglove.{kind}", "protobuf", _descriptor_set(kind), "protobuf"


def is_raw(topic: str) -> bool:
    return topic in RAW_TOPICS


# --------------------------------------------------------------------------- point clouds

def _stamp_ns(stamp: float) -> int:
    return max(int(round(stamp * 1e9)), 0)


def _time(stamp: float) -> dict:
    ns = _stamp_ns(stamp)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _set_time(ts: Any, stamp: float) -> None:
    ns = _stamp_ns(stamp)
    ts.seconds, ts.nanos = ns // 1_000_000_000, ns % 1_000_000_000


def point_cloud(points: np.ndarray, names: tuple[str, ...], stamp: float, frame_id: str) -> bytes:
    """A foxglove.PointCloud (protobuf bytes) of float32 columns `names`; stamp in s."""
    pts = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, len(names)))
    msg = _foxglove("PointCloud")()
    _set_time(msg.timestamp, stamp)
    msg.frame_id = frame_id
    msg.pose.orientation.w = 1.0
    msg.point_stride = 4 * len(names)
    for i, name in enumerate(names):
        field = msg.fields.add()
        field.name, field.offset, field.type = name, 4 * i, FLOAT32
    msg.data = pts.tobytes()
    return msg.SerializeToString()


def points_message(points: np.ndarray, stamp: float, vehicle: str) -> bytes:
    """/radar/points: a vehicle's float32 (N, 5) x, y, z, doppler, snr in `<vehicle>/radar`."""
    return point_cloud(points, POINT_FIELDS, stamp, radar_frame(vehicle))


def point_cloud_from_bytes(data: bytes, names: tuple[str, ...]) -> tuple[np.ndarray, float, str]:
    """(float32 (N, len(names)) points, stamp s, frame id) of a foxglove.PointCloud whose
    fields are exactly `names`, packed float32; ParseError otherwise."""
    from google.protobuf.message import DecodeError

    msg = _foxglove("PointCloud")()
    try:
        msg.ParseFromString(data)
    except DecodeError as exc:
        raise ParseError(f"bad point cloud record: {exc}") from exc
    layout = [(f.name, f.offset, f.type) for f in msg.fields]
    if layout != [(n, 4 * i, FLOAT32) for i, n in enumerate(names)] or msg.point_stride != 4 * len(names):
        raise ParseError(f"point cloud layout is not {', '.join(names)} float32")
    if len(msg.data) % msg.point_stride:
        raise ParseError("point cloud data is not a whole number of points")
    pts = np.frombuffer(msg.data, dtype="<f4").reshape(-1, len(names)).astype(np.float32)
    return pts, msg.timestamp.seconds + msg.timestamp.nanos * 1e-9, msg.frame_id


def points_from_message(data: bytes, encoding: str = "protobuf") -> tuple[np.ndarray, float]:
    """(float32 (N, 5) points, stamp s) of a /radar/points record; `encoding` "json" reads the
    JSON point clouds of logs written before the protobuf schemas."""
    if encoding == "json":
        try:
            msg = json.loads(data)
            if msg["point_stride"] != 20 or [f["name"] for f in msg["fields"]] != list(POINT_FIELDS):
                raise ParseError("point cloud layout is not x, y, z, doppler, snr float32")
            raw = base64.b64decode(msg["data"])
            stamp = msg["timestamp"]["sec"] + msg["timestamp"]["nsec"] * 1e-9
        except (KeyError, TypeError, ValueError) as exc:
            raise ParseError(f"bad point cloud record: {exc}") from exc
        if len(raw) % 20:
            raise ParseError("point cloud data is not a whole number of points")
        return np.frombuffer(raw, dtype="<f4").reshape(-1, 5).astype(np.float32), stamp
    pts, stamp, _ = point_cloud_from_bytes(data, POINT_FIELDS)
    return pts, stamp


def stamp_key(stamp: float) -> int:
    """Integer ns key used to join a frame record with its point cloud."""
    return int(round(stamp * 1e9))


# --------------------------------------------------------------------------- scene entities

def _quat_z(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by `yaw` rad about z."""
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


def quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) unit quaternion of a 3x3 rotation matrix (w >= 0)."""
    R = np.asarray(R, np.float64)
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2
    y = math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2
    z = math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2
    x = math.copysign(x, R[2, 1] - R[1, 2])
    y = math.copysign(y, R[0, 2] - R[2, 0])
    z = math.copysign(z, R[1, 0] - R[0, 1])
    n = math.sqrt(x * x + y * y + z * z + w * w)
    return x / n, y / n, z / n, w / n


def _entity(update: Any, stamp: float, frame_id: str, entity_id: str) -> Any:
    e = update.entities.add()
    _set_time(e.timestamp, stamp)
    e.frame_id, e.id = frame_id, entity_id
    return e


def _box(e: Any, x: float, y: float, z: float, colour: tuple, label: str) -> None:
    cube = e.cubes.add()
    cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = x, y, z
    cube.pose.orientation.w = 1.0
    cube.size.x, cube.size.y, cube.size.z = VEHICLE_BOX_M
    cube.color.r, cube.color.g, cube.color.b, cube.color.a = colour
    text = e.texts.add()
    text.pose.position.x, text.pose.position.y = x, y
    text.pose.position.z = z + VEHICLE_BOX_M[2]
    text.pose.orientation.w = 1.0
    text.billboard, text.font_size, text.scale_invariant = True, 14.0, True
    text.color.r = text.color.g = text.color.b = text.color.a = 1.0
    text.text = label


def _meta(e: Any, **values: Any) -> None:
    for k, v in values.items():
        kv = e.metadata.add()
        kv.key, kv.value = k, "" if v is None else str(v)


def _new_update(stamp: float) -> Any:
    """A SceneUpdate that first deletes every earlier entity (each update is the whole view)."""
    update = _foxglove("SceneUpdate")()
    deletion = update.deletions.add()
    _set_time(deletion.timestamp, stamp)
    deletion.type = _foxglove("SceneEntityDeletion").ALL
    return update


def _centre_z(radar_height: float) -> float:
    """z of a vehicle's box centre in a radar frame: the road is radar_height below it."""
    return VEHICLE_BOX_M[2] / 2 - float(radar_height)


# --------------------------------------------------------------------------- shared frames

def shared_topic(vehicle: str | None, view: str = "") -> str:
    """The wire topic of shared frames (own: vehicle None; received: the sender) + a view."""
    return (SHARED_TX if vehicle is None else SHARED_RX_PREFIX + vehicle) + view


def _shared_wire(payload: bytes, frame: Any) -> dict:
    stamp = float(frame.stamp)
    return {"timestamp": _time(stamp), "sender": frame.sender, "seq": int(frame.seq), "stamp": stamp,
            "data": base64.b64encode(bytes(payload)).decode("ascii")}


def _shared_points(frame: Any) -> bytes:
    pts = np.asarray(frame.vehicle_points, np.float32).reshape(-1, 5)
    idx = np.asarray(frame.vehicle_index, np.float32).reshape(-1, 1)
    return point_cloud(np.hstack([pts, idx]), SHARED_POINT_FIELDS, float(frame.stamp), radar_frame(frame.sender))


def _shared_background(frame: Any) -> bytes:
    return point_cloud(frame.background, ("x", "y", "z"), float(frame.stamp), radar_frame(frame.sender))


def _shared_vehicles(frame: Any) -> bytes:
    stamp = float(frame.stamp)
    fid = radar_frame(frame.sender)
    update = _new_update(stamp)
    z = _centre_z(frame.radar_height)
    boxes = np.asarray(frame.vehicle_boxes, np.float32).reshape(-1, 6)
    for i, (x, y) in enumerate(np.asarray(frame.vehicle_centers, np.float64).reshape(-1, 2)):
        e = _entity(update, stamp, fid, f"{frame.sender}/{i}")
        _box(e, float(x), float(y), z, SOURCE_COLOURS[1], f"{frame.sender} {i}")
        _meta(e, score=f"{boxes[i, 4]:.2f}" if i < len(boxes) else None,
              camera_depth_m=f"{boxes[i, 5]:.2f}" if i < len(boxes) else None)
    return update.SerializeToString()


Record = tuple[str, Callable[[], "bytes | dict"]]


def shared_records(topic: str, payload: bytes, frame: Any) -> list[Record]:
    """The records of one shared frame under its wire topic `topic` (shared_topic): the wire
    bytes, and the decoded frame `frame` (SharedFrame, not changed afterwards) as Foxglove
    point clouds and scene. Each comes as (topic, builder) for `Recorder.write`, which calls
    the builder on its writer thread."""
    return [
        (topic, functools.partial(_shared_wire, payload, frame)),
        (topic + SHARED_POINTS, functools.partial(_shared_points, frame)),
        (topic + SHARED_BACKGROUND, functools.partial(_shared_background, frame)),
        (topic + SHARED_VEHICLES, functools.partial(_shared_vehicles, frame)),
    ]


def shared_payload(data: bytes, encoding: str) -> bytes:
    """The wire bytes of a /shared/tx or /shared/rx/<v> record (JSON, or raw in older logs)."""
    if encoding != "json":
        return bytes(data)
    try:
        return base64.b64decode(json.loads(data)["data"], validate=True)
    except (KeyError, TypeError, ValueError) as exc:
        raise ParseError(f"bad shared frame record: {exc}") from exc


# --------------------------------------------------------------------------- fused results

def _finite(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _fused_cavs(msg: dict) -> list[dict]:
    return [c for c in msg.get("cavs", []) if c.get("status") == "fused" and c.get("T_ego_cav") is not None]


def _transforms(msg: dict) -> bytes:
    stamp = float(msg["stamp"])
    transforms = _foxglove("FrameTransforms")()
    for cav in _fused_cavs(msg):
        T = np.asarray(cav["T_ego_cav"], np.float64).reshape(4, 4)
        tf = transforms.transforms.add()
        _set_time(tf.timestamp, stamp)
        tf.parent_frame_id, tf.child_frame_id = radar_frame(msg["vehicle"]), radar_frame(cav["id"])
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in T[:3, 3])
        r = tf.rotation
        r.x, r.y, r.z, r.w = quaternion(T[:3, :3])
    return transforms.SerializeToString()


def _quality(msg: dict, cav: dict) -> dict:
    cov = cav.get("covariance")
    return {"timestamp": _time(float(msg["stamp"])), "parent_frame_id": radar_frame(msg["vehicle"]),
            "child_frame_id": radar_frame(cav["id"]), "status": cav.get("status", ""),
            "reason": cav.get("reason", ""), "confidence": _finite(cav.get("confidence")),
            "covariance": None if cov is None else [_finite(v) for v in np.ravel(np.asarray(cov, object))]}


def _scene(msg: dict, radar_height: float) -> bytes:
    stamp = float(msg["stamp"])
    ego = radar_frame(msg["vehicle"])
    update = _new_update(stamp)
    for cav in _fused_cavs(msg):
        T = np.asarray(cav["T_ego_cav"], np.float64).reshape(4, 4)
        forward = T[:3, :3] @ np.array([0.0, 1.0, 0.0])     # the CAV radar's boresight
        e = _entity(update, stamp, ego, f"{cav['id']}/radar")
        arrow = e.arrows.add()
        arrow.pose.position.x, arrow.pose.position.y, arrow.pose.position.z = (float(v) for v in T[:3, 3])
        o = arrow.pose.orientation
        o.x, o.y, o.z, o.w = _quat_z(math.atan2(forward[1], forward[0]))
        arrow.shaft_length, arrow.shaft_diameter, arrow.head_length, arrow.head_diameter = 3.0, 0.3, 1.0, 0.8
        arrow.color.r, arrow.color.g, arrow.color.b, arrow.color.a = SOURCE_COLOURS[1]
        _meta(e, vehicle=cav["id"], confidence=_finite(cav.get("confidence")),
              pairs=len(cav.get("pairs", [])), reason=cav.get("reason", ""))
    z = _centre_z(radar_height)
    tracks = {int(t["id"]): t for t in msg.get("tracks", []) if isinstance(t, dict) and "id" in t}
    seen: set[int] = set()
    for row in msg.get("objects", []):  # x, y, source, index[, track id]: ids per frame until tracked
        x, y, src, index = float(row[0]), float(row[1]), int(row[2]), int(row[3])
        track = int(row[4]) if len(row) > 4 and row[4] >= 0 else None
        if track is not None and track in seen:       # a second detection of one tracked vehicle
            track = None
        if track is not None:
            seen.add(track)
        name = SOURCE_NAMES.get(src, str(src))
        e = _entity(update, stamp, ego, f"{name}/{index}" if track is None else f"track/{track}")
        label = f"{name} {index}" if track is None else f"#{track} ({name})"
        _box(e, x, y, z, SOURCE_COLOURS.get(src, (1.0, 1.0, 1.0, 0.5)), label)
        t = tracks.get(track) if track is not None else None
        if t is not None:
            _heading(e, x, y, z, float(t["vx"]), float(t["vy"]))
            _meta(e, source=name, index=index, track=track, vx=round(float(t["vx"]), 3), vy=round(float(t["vy"]), 3))
        else:
            _meta(e, source=name, index=index, track=track)
    return update.SerializeToString()


def _heading(e: Any, x: float, y: float, z: float, vx: float, vy: float) -> None:
    """A tracked object's box turned along its ground velocity (m/s, Ego radar frame), with an
    arrow as long as the way it covers in one second; a vehicle slower than MIN_HEADING_MPS
    keeps the axis-aligned box (its heading is unknown)."""
    speed = math.hypot(vx, vy)
    if speed < MIN_HEADING_MPS:
        return
    yaw = math.atan2(vy, vx)                                 # the velocity's direction from +x
    o = e.cubes[0].pose.orientation
    o.x, o.y, o.z, o.w = _quat_z(yaw - math.pi / 2)          # the box's length lies along y
    arrow = e.arrows.add()
    arrow.pose.position.x, arrow.pose.position.y, arrow.pose.position.z = x, y, z + VEHICLE_BOX_M[2] / 2
    a = arrow.pose.orientation
    a.x, a.y, a.z, a.w = _quat_z(yaw)                        # Foxglove arrows point along +x
    arrow.shaft_length, arrow.shaft_diameter = max(speed - 0.5, 0.1), 0.15
    arrow.head_length, arrow.head_diameter = 0.5, 0.4
    arrow.color.r = arrow.color.g = arrow.color.b = arrow.color.a = 1.0


def fused_records(msg: dict, radar_height: float) -> list[Record]:
    """The Foxglove view of one fused message `msg` (not changed afterwards; docs/formats.md):
    the transforms of the fused CAVs on /tf, each CAV's transform quality on /tf/quality, the
    objects on /fused/objects; as (topic, builder) for `Recorder.write`."""
    out: list[Record] = []
    if _fused_cavs(msg):
        out.append((TF, functools.partial(_transforms, msg)))
    out += [(TF_QUALITY, functools.partial(_quality, msg, cav)) for cav in msg.get("cavs", [])]
    out.append((FUSED_OBJECTS, functools.partial(_scene, msg, radar_height)))
    return out


# --------------------------------------------------------------------------- sensor frames

def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype="<f4").tobytes()).decode("ascii")


def _unb64(s: str, cols: int) -> np.ndarray:
    raw = base64.b64decode(s)
    if len(raw) % (4 * cols):
        raise ParseError("array size mismatch")
    return np.frombuffer(raw, dtype="<f4").reshape(-1, cols).astype(np.float32)


@dataclass
class SensorFrame:
    """What one tick of the loop processes: a radar frame and the camera detections used.

    points: float32 (N, 5) radar frame; boxes: float32 (M, 6); features: float32 (M, 32);
    stamp: radar capture time on the shared clock, s; camera_stamp: detections' time, s
    (nan when none); seq: this vehicle's frame counter; frame_number: device counter.
    """

    seq: int
    stamp: float
    points: np.ndarray
    boxes: np.ndarray
    features: np.ndarray
    camera_stamp: float = float("nan")
    frame_number: int = -1
    host_time: float = 0.0


def frame_to_json(f: SensorFrame) -> dict:
    return {
        "seq": int(f.seq), "stamp": float(f.stamp), "stamp_ns": stamp_key(f.stamp),
        "host_time": float(f.host_time), "frame_number": int(f.frame_number),
        "camera_stamp": None if not np.isfinite(f.camera_stamp) else float(f.camera_stamp),
        "boxes": _b64(np.asarray(f.boxes).reshape(-1, 6)),
        "features": _b64(np.asarray(f.features).reshape(-1, 32)),
        "num_points": int(len(f.points)),
    }


def frame_from_json(msg: dict, points: np.ndarray) -> SensorFrame:
    try:
        cam = msg.get("camera_stamp")
        return SensorFrame(
            seq=int(msg["seq"]), stamp=float(msg["stamp"]), points=points,
            boxes=_unb64(msg["boxes"], 6), features=_unb64(msg["features"], 32),
            camera_stamp=float("nan") if cam is None else float(cam),
            frame_number=int(msg.get("frame_number", -1)), host_time=float(msg.get("host_time", 0.0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ParseError(f"bad frame record: {exc}") from exc


def camera_to_meta(camera: Any, radar_height: float) -> dict[str, str]:
    """MCAP metadata (string map) holding the camera model and the radar height."""
    return {"K": json.dumps(np.asarray(camera.K, float).tolist()),
            "image_size": json.dumps([int(v) for v in camera.image_size]),
            "T_cam_radar": json.dumps(np.asarray(camera.T_cam_radar, float).tolist()),
            "radar_height": repr(float(radar_height))}


def camera_from_meta(meta: dict[str, str]) -> tuple[Any, float]:
    """(CameraModel, radar_height m) back from `camera_to_meta`."""
    from mmatch.types import CameraModel

    try:
        K = np.array(json.loads(meta["K"]), np.float64).reshape(3, 3)
        size = tuple(int(v) for v in json.loads(meta["image_size"]))
        T = np.array(json.loads(meta["T_cam_radar"]), np.float64).reshape(4, 4)
        return CameraModel(K=K, image_size=(size[0], size[1]), T_cam_radar=T), float(meta["radar_height"])
    except (KeyError, ValueError, TypeError) as exc:
        raise ParseError(f"bad camera metadata: {exc}") from exc
