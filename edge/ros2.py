"""A field log as a ROS 2 bag (rosbags; no ROS installation needed).

Every channel with a Foxglove schema becomes its ROS 2 counterpart on the same topic:
`foxglove.PointCloud` -> `sensor_msgs/msg/PointCloud2`, `foxglove.FrameTransforms` (`/tf`) ->
`tf2_msgs/msg/TFMessage`, `foxglove.SceneUpdate` (fused objects, shared vehicles) ->
`visualization_msgs/msg/MarkerArray`; JSON channels (`/fused`, `/tf/quality`, ...) become
`std_msgs/msg/String` holding the JSON. Raw device bytes are left out. `/tf_static` adds, for
every vehicle, `<vehicle>/radar_flu` (REP-103 axes: x forward, y left, z up) -> `<vehicle>/radar`
(MMatch axes: x right, y forward, z up), so ROS tools can show everything in REP-103 axes
(docs/prerequisites.md). Bag message times are the log times; header stamps the capture
stamps. Message definitions are ROS 2 Humble's, stored in the bag.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mmatch.edge import logreader, logschema
from mmatch.errors import ConfigError, ParseError

log = logging.getLogger(__name__)

INSTALL_HINT = "the ROS 2 export needs rosbags: pip install 'mmatch[ros2]' (or pip install rosbags)"

#: foxglove.NumericType -> sensor_msgs/PointField datatype (the integer codes differ)
POINT_FIELD_TYPES = {1: 2, 2: 1, 3: 4, 4: 3, 5: 6, 6: 5, 7: 7, 8: 8}
#: rotation taking MMatch radar coordinates (x right, y forward) to REP-103 (x forward, y left)
FLU_FROM_RADAR = (0.0, 0.0, -math.sqrt(0.5), math.sqrt(0.5))  # x, y, z, w: -90 deg about z


def _typestore() -> Any:
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:
        raise ConfigError(INSTALL_HINT) from exc
    return get_typestore(Stores.ROS2_HUMBLE)


class _Stamp:
    """A protobuf-Timestamp-like (seconds, nanos) of an ns time."""

    def __init__(self, ns: int) -> None:
        self.seconds, self.nanos = divmod(int(ns), 1_000_000_000)


class _Converter:
    """Foxglove protobuf records -> rosbags message objects of one typestore."""

    def __init__(self, ts: Any) -> None:
        self.ts = ts
        t = ts.types
        self.Header, self.Time = t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"]
        self.Duration = t["builtin_interfaces/msg/Duration"]
        self.PointCloud2, self.PointField = t["sensor_msgs/msg/PointCloud2"], t["sensor_msgs/msg/PointField"]
        self.TFMessage, self.TransformStamped = t["tf2_msgs/msg/TFMessage"], t["geometry_msgs/msg/TransformStamped"]
        self.Transform, self.Vector3 = t["geometry_msgs/msg/Transform"], t["geometry_msgs/msg/Vector3"]
        self.Quaternion, self.Pose, self.Point = (t["geometry_msgs/msg/Quaternion"], t["geometry_msgs/msg/Pose"],
                                                  t["geometry_msgs/msg/Point"])
        self.Marker, self.MarkerArray = t["visualization_msgs/msg/Marker"], t["visualization_msgs/msg/MarkerArray"]
        self.ColorRGBA, self.String = t["std_msgs/msg/ColorRGBA"], t["std_msgs/msg/String"]
        self.CompressedImage, self.MeshFile = t["sensor_msgs/msg/CompressedImage"], t["visualization_msgs/msg/MeshFile"]

    def header(self, ts: Any, frame_id: str) -> Any:
        return self.Header(stamp=self.Time(sec=int(ts.seconds), nanosec=int(ts.nanos)), frame_id=frame_id)

    def point_cloud(self, m: Any) -> Any:
        if m.pose.orientation.w != 1.0 or any((m.pose.position.x, m.pose.position.y, m.pose.position.z,
                                              m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z)):
            raise ParseError("point cloud with a non-identity pose (not written by MMatch)")
        n = len(m.data) // m.point_stride if m.point_stride else 0
        fields = []
        for f in m.fields:
            if f.type not in POINT_FIELD_TYPES:
                raise ParseError(f"point field {f.name!r} of unknown type {f.type}")
            fields.append(self.PointField(name=f.name, offset=int(f.offset), datatype=POINT_FIELD_TYPES[f.type],
                                          count=1))
        return self.PointCloud2(header=self.header(m.timestamp, m.frame_id), height=1, width=n, fields=fields,
                                is_bigendian=False, point_step=int(m.point_stride),
                                row_step=int(m.point_stride) * n,
                                data=np.frombuffer(m.data, np.uint8).copy(), is_dense=True)

    def transform(self, stamp: Any, parent: str, child: str, t: tuple, q: tuple) -> Any:
        return self.TransformStamped(
            header=self.header(stamp, parent), child_frame_id=child,
            transform=self.Transform(translation=self.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                                     rotation=self.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                              w=float(q[3]))))

    def transforms(self, m: Any) -> Any:
        return self.TFMessage(transforms=[
            self.transform(tf.timestamp, tf.parent_frame_id, tf.child_frame_id,
                           (tf.translation.x, tf.translation.y, tf.translation.z),
                           (tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w)) for tf in m.transforms])

    def _marker(self, header: Any, ns: str, k: int, kind: int, pose: Any | None, scale: tuple,
                colour: tuple, text: str = "", action: int = 0) -> Any:
        """A Marker; pose: a foxglove Pose (None: identity), colour: (r, g, b, a)."""
        p, q = ((pose.position.x, pose.position.y, pose.position.z),
                (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w)) \
            if pose is not None else ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        empty = np.zeros(0, np.uint8)
        return self.Marker(
            header=header, ns=ns, id=k, type=kind, action=action,
            pose=self.Pose(position=self.Point(x=p[0], y=p[1], z=p[2]),
                           orientation=self.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])),
            scale=self.Vector3(x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
            color=self.ColorRGBA(r=colour[0], g=colour[1], b=colour[2], a=colour[3]),
            lifetime=self.Duration(sec=0, nanosec=0), frame_locked=False, points=[], colors=[],
            texture_resource="", texture=self.CompressedImage(header=header, format="", data=empty),
            uv_coordinates=[], text=text, mesh_resource="",
            mesh_file=self.MeshFile(filename="", data=empty), mesh_use_embedded_materials=False)

    def scene(self, m: Any, stamp: Any) -> Any:
        M = self.Marker
        rgba = lambda c: (c.r, c.g, c.b, c.a)  # noqa: E731
        markers = []
        if m.deletions:  # our updates replace the whole view: delete every earlier marker first
            markers.append(self._marker(self.header(stamp, ""), "", 0, M.CUBE, None, (0, 0, 0), (0, 0, 0, 0),
                                        action=M.DELETEALL))
        for e in m.entities:
            header = self.header(e.timestamp, e.frame_id)
            shapes = ([(M.CUBE, c.pose, (c.size.x, c.size.y, c.size.z), rgba(c.color), "") for c in e.cubes]
                      + [(M.ARROW, a.pose, (a.shaft_length + a.head_length, a.shaft_diameter, a.head_diameter),
                          rgba(a.color), "") for a in e.arrows]
                      + [(M.TEXT_VIEW_FACING, t.pose, (0, 0, 1.0), rgba(t.color), t.text) for t in e.texts])
            for k, (kind, pose, scale, colour, text) in enumerate(shapes):
                markers.append(self._marker(header, e.id, k, kind, pose, scale, colour, text))
        return self.MarkerArray(markers=markers)


def _decoders() -> dict[str, Callable[[bytes], Any]]:
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    return {"foxglove.PointCloud": PointCloud.FromString, "foxglove.FrameTransforms": FrameTransforms.FromString,
            "foxglove.SceneUpdate": SceneUpdate.FromString}


ROS_TYPES = {"foxglove.PointCloud": "sensor_msgs/msg/PointCloud2", "foxglove.FrameTransforms": "tf2_msgs/msg/TFMessage",
             "foxglove.SceneUpdate": "visualization_msgs/msg/MarkerArray"}


def export_ros2(log_path: str | Path, out: str | Path, *, storage: str = "sqlite3") -> dict[str, Any]:
    """Write the log (file or folder) as a ROS 2 bag folder `out` (must not exist); returns
    {"bag", "topics": {topic: {"type", "messages"}}, "skipped": {topic: n}, "truncated"}."""
    ts = _typestore()
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer

    out = Path(out)
    if out.exists():
        raise ConfigError(f"{out}: exists; the bag is written into a new folder")
    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    conv = _Converter(ts)
    decode = _decoders()
    report = logreader.LogReport()
    counts: Counter = Counter()
    skipped: Counter = Counter()
    types: dict[str, str] = {}
    frames: set[str] = set()
    zero = QosTime(sec=0, nsec=0)
    latched = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, zero, zero,
                  QosLiveliness.AUTOMATIC, zero, False)
    with Writer(out, version=8, storage_plugin=plugin) as writer:
        connections: dict[str, Any] = {}

        def put(topic: str, msgtype: str, msg: Any, t_ns: int, qos: tuple = ()) -> None:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts, offered_qos_profiles=qos)
                types[topic] = msgtype
            writer.write(connections[topic], t_ns, ts.serialize_cdr(msg, msgtype))
            counts[topic] += 1

        static_done: set[str] = set()
        for m in logreader.read_messages(log_path, report=report):
            try:
                if m.schema in decode:
                    pb = decode[m.schema](m.data)
                    if m.schema == "foxglove.PointCloud":
                        ros = conv.point_cloud(pb)
                        frames.add(pb.frame_id)
                    elif m.schema == "foxglove.FrameTransforms":
                        ros = conv.transforms(pb)
                        frames.update(f for tf in pb.transforms for f in (tf.parent_frame_id, tf.child_frame_id))
                    else:
                        stamp = pb.entities[0].timestamp if pb.entities else (
                            pb.deletions[0].timestamp if pb.deletions else None)
                        if stamp is None:
                            continue
                        ros = conv.scene(pb, stamp)
                    new = sorted(f for f in frames if f.endswith("/radar") and f not in static_done)
                    if new:  # every radar frame so far, latched (a later one replaces it)
                        static_done.update(new)
                        put("/tf_static", "tf2_msgs/msg/TFMessage", conv.TFMessage(transforms=[
                            conv.transform(_Stamp(m.log_time_ns), f + "_flu", f, (0, 0, 0), FLU_FROM_RADAR)
                            for f in sorted(static_done)]), m.log_time_ns, (latched,))
                    put(m.topic, ROS_TYPES[m.schema], ros, m.log_time_ns)
                elif m.encoding == "json":
                    put(m.topic, "std_msgs/msg/String", conv.String(data=m.data.decode("utf-8")), m.log_time_ns)
                else:
                    skipped[m.topic] += 1
            except (ParseError, ValueError, UnicodeDecodeError) as exc:
                skipped[m.topic] += 1
                log.warning("%s: record skipped: %s", m.topic, exc)
    if not counts:
        raise ParseError(f"{log_path}: no message to export")
    return {"bag": str(out), "storage": storage,
            "topics": {t: {"type": types[t], "messages": n} for t, n in sorted(counts.items())},
            "skipped": dict(sorted(skipped.items())), "truncated": report.truncated}
