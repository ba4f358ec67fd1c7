"""What the field log holds: topics, their MCAP schemas, and record encoders/decoders.

Topics (MCAP channels):

| topic | encoding | content |
| --- | --- | --- |
| /raw/uart | x-ti-uart (raw bytes) | UART data-port bytes as read (raw data: stops first when disk runs low) |
| /raw/dca1000 | x-dca1000-frame | one raw ADC frame (raw data) |
| /radar/points | json, schema foxglove.PointCloud | the radar points of each processed frame, Foxglove displays them |
| /vehicle/frame | json, mmatch.SensorFrame | seq, stamps, camera detections + descriptors of each processed frame |
| /shared/tx | x-mmatch-shared | encoded shared frames this vehicle published |
| /shared/rx/<vehicle> | x-mmatch-shared | encoded shared frames received from <vehicle> |
| /fused | json, mmatch.Fused | the Ego's fusion result per frame |
| /health | json, mmatch.Health | rates and drops |

Log times are the recorder's strictly increasing clock (ns), so file order is the order in
which the loop saw things; replaying in that order reproduces the live pairing.
"""

from __future__ import annotations

import base64
import json
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
HEALTH = "/health"

RAW_TOPICS = (RAW_UART, RAW_DCA)

# foxglove.PointCloud as JSON schema (bytes fields are base64 strings in JSON encoding).
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
POINTCLOUD_SCHEMA = {
    "title": "foxglove.PointCloud",
    "description": "A collection of N-dimensional points, which may contain additional fields with "
                   "information like normals, intensity, etc.",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "title": "time",
                      "properties": {"sec": {"type": "integer", "minimum": 0},
                                     "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
        "point_stride": {"type": "integer", "minimum": 0},
        "fields": {"type": "array", "items": {
            "type": "object", "title": "foxglove.PackedElementField",
            "properties": {"name": {"type": "string"}, "offset": {"type": "integer", "minimum": 0},
                           "type": {"type": "integer", "title": "foxglove.NumericType",
                                    "description": "FLOAT32 = 7"}}}},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}
FLOAT32 = 7
POINT_FIELDS = ("x", "y", "z", "doppler", "snr")

SCHEMAS: dict[str, tuple[str, str, bytes, str]] = {
    # topic: (schema name, schema encoding, schema data, message encoding)
    RAW_UART: ("mmatch.RawUart", "", b"", "x-ti-uart"),
    RAW_DCA: ("mmatch.RawDca1000", "", b"", "x-dca1000-frame"),
    POINTS: ("foxglove.PointCloud", "jsonschema", json.dumps(POINTCLOUD_SCHEMA).encode(), "json"),
    FRAME: ("mmatch.SensorFrame", "jsonschema", json.dumps({
        "type": "object", "properties": {
            "seq": {"type": "integer"}, "stamp": {"type": "number"}, "host_time": {"type": "number"},
            "frame_number": {"type": "integer"}, "camera_stamp": {"type": "number"},
            "boxes": {"type": "array"}, "features": {"type": "string", "contentEncoding": "base64"}}}).encode(),
        "json"),
    SHARED_TX: ("mmatch.SharedFrameWire", "", b"", "x-mmatch-shared"),
    FUSED: ("mmatch.Fused", "jsonschema", json.dumps({"type": "object"}).encode(), "json"),
    HEALTH: ("mmatch.Health", "jsonschema", json.dumps({"type": "object"}).encode(), "json"),
}


def schema_for(topic: str) -> tuple[str, str, bytes, str]:
    """(schema name, schema encoding, schema data, message encoding) of a topic."""
    if topic.startswith(SHARED_RX_PREFIX):
        return SCHEMAS[SHARED_TX]
    try:
        return SCHEMAS[topic]
    except KeyError:
        raise ValueError(f"unknown log topic {topic!r}") from None


def is_raw(topic: str) -> bool:
    return topic in RAW_TOPICS


def _time(stamp: float) -> dict:
    ns = int(round(stamp * 1e9))
    return {"sec": max(ns, 0) // 1_000_000_000, "nsec": max(ns, 0) % 1_000_000_000}


def points_to_json(points: np.ndarray, stamp: float, frame_id: str = "radar") -> dict:
    """A foxglove.PointCloud (JSON encoding) of float32 (N, 5) x, y, z, doppler, snr points."""
    pts = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 5)
    return {
        "timestamp": _time(stamp),
        "frame_id": frame_id,
        "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                 "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "point_stride": 20,
        "fields": [{"name": n, "offset": 4 * i, "type": FLOAT32} for i, n in enumerate(POINT_FIELDS)],
        "data": base64.b64encode(pts.tobytes()).decode("ascii"),
    }


def points_from_json(msg: dict) -> tuple[np.ndarray, float]:
    """(float32 (N, 5) points, stamp s) back from `points_to_json` output."""
    try:
        if msg["point_stride"] != 20 or [f["name"] for f in msg["fields"]] != list(POINT_FIELDS):
            raise ParseError("point cloud layout is not x, y, z, doppler, snr float32")
        raw = base64.b64decode(msg["data"])
        if len(raw) % 20:
            raise ParseError("point cloud data is not a whole number of points")
        stamp = msg["timestamp"]["sec"] + msg["timestamp"]["nsec"] * 1e-9
    except (KeyError, TypeError, ValueError) as exc:
        raise ParseError(f"bad point cloud record: {exc}") from exc
    return np.frombuffer(raw, dtype="<f4").reshape(-1, 5).astype(np.float32), stamp


def stamp_key(stamp: float) -> int:
    """Integer ns key used to join a frame record with its point cloud."""
    return int(round(stamp * 1e9))


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
