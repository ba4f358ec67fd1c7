"""Replay: field logs and raw UART captures back through the per-frame Node.

A log (MCAP file or folder) becomes a stream of events in the order the live loop saw
them: own sensor frames (point cloud + frame record, joined by capture stamp) and shared
frames received from other vehicles. Fed to a `Node` in that order, they reproduce the
live fused results (`compare_fused`). A raw UART capture (the bytes of a data port)
becomes radar frames through the TI streaming reader, the same parser a live port uses.
Pacing: as fast as possible, or at the recorded pace (log times; for raw captures the
serial line rate, 10 bits per byte).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mmatch.edge import logreader, logschema
from mmatch.edge.logschema import SensorFrame
from mmatch.errors import ParseError
from mmatch.types import RadarFrame

log = logging.getLogger(__name__)


FIRST_FILE_SUFFIX = "-0000.mcap"  # the recorder's first file of a run


@dataclass
class Event:
    """kind: "frame" (own sensor frame), "rx" (shared frame from `vehicle`), "fused"
    (a recorded fusion result), "raw" (raw sensor bytes), "run" (a new run of the service
    starts in this log folder: the live state was fresh)."""

    kind: str
    log_time_ns: int
    frame: SensorFrame | None = None
    vehicle: str = ""
    data: bytes = b""
    msg: dict | None = None


class Pacer:
    """Sleeps so that event times (ns) are replayed at `speed` x real time; no-op when fast."""

    def __init__(self, fast: bool, speed: float = 1.0, sleep: Callable[[float], None] = time.sleep) -> None:
        self.fast, self.speed, self.sleep = fast, speed, sleep
        self._t0: tuple[int, float] | None = None

    def wait(self, t_ns: int) -> None:
        if self.fast:
            return
        if self._t0 is None:
            self._t0 = (t_ns, time.monotonic())
            return
        due = self._t0[1] + (t_ns - self._t0[0]) / 1e9 / self.speed
        delay = due - time.monotonic()
        if delay > 0:
            self.sleep(delay)


def log_events(path: str | Path, report: logreader.LogReport | None = None,
               raw: bool = False) -> Iterator[Event]:
    """The events of a log in file order (= the live loop's order)."""
    pending: dict[int, np.ndarray] = {}
    current = None
    for m in logreader.read_messages(path, report=report):
        if m.file != current:
            if current is not None and Path(m.file).name.endswith(FIRST_FILE_SUFFIX):
                pending.clear()
                yield Event("run", m.log_time_ns)  # a new process started (e.g. restarted by systemd)
            current = m.file
        try:
            if m.topic == logschema.POINTS:
                pts, stamp = logschema.points_from_message(m.data, m.encoding)
                pending[logschema.stamp_key(stamp)] = pts
                if len(pending) > 64:
                    pending.pop(next(iter(pending)))
            elif m.topic == logschema.FRAME:
                msg = json.loads(m.data)
                pts = pending.pop(int(msg["stamp_ns"]), None)
                if pts is None:
                    log.warning("frame %s has no point cloud in the log; skipped", msg.get("seq"))
                    continue
                yield Event("frame", m.log_time_ns, frame=logschema.frame_from_json(msg, pts))
            elif m.topic.startswith(logschema.SHARED_RX_PREFIX):
                shared = logschema.parse_shared_topic(m.topic)
                if shared is not None and not shared[2]:  # the wire record, not a decoded view
                    yield Event("rx", m.log_time_ns, vehicle=shared[1],
                                data=logschema.shared_payload(m.data, m.encoding))
            elif m.topic == logschema.FUSED:
                yield Event("fused", m.log_time_ns, msg=json.loads(m.data))
            elif raw and m.topic == logschema.RAW_UART:
                yield Event("raw", m.log_time_ns, data=m.data)
        except (ParseError, ValueError, KeyError, TypeError) as exc:
            log.warning("skipping a bad %s record: %s", m.topic, exc)


def recorded_budget_skips(path: str | Path) -> dict[tuple[int, int], list[str]]:
    """{(seq, stamp ns): CAV ids} the live run left out of a frame for its time budget."""
    out: dict[tuple[int, int], list[str]] = {}
    for m in logreader.read_messages(path, topics=[logschema.FUSED]):
        try:
            msg = json.loads(m.data)
            if msg.get("budget_skipped"):
                out[(int(msg["seq"]), logschema.stamp_key(float(msg["stamp"])))] = list(msg["budget_skipped"])
        except (ValueError, KeyError, TypeError):
            continue
    return out


def log_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The metadata records of a log's first file, by name ("config", "camera")."""
    report = logreader.LogReport()
    for _ in logreader.read_messages(path, report=report):
        break  # metadata comes right after the header, before any message
    return {k.split(":", 1)[1]: v for k, v in report.metadata.items()}


def log_config_text(path: str | Path) -> str | None:
    """The effective config TOML stored in a log, if any."""
    return log_metadata(path).get("config", {}).get("toml")


def capture_frames(path: str | Path, *, pace_baud: int | None = None, chunk: int = 4096,
                   sleep: Callable[[float], None] = time.sleep,
                   stats_out: dict | None = None) -> Iterator[RadarFrame]:
    """Radar frames of a raw UART capture through the TI streaming reader.

    pace_baud: feed bytes at this line rate (8N1: 10 bits per byte), else as fast as possible.
    """
    from mmatch.drivers.ti.reader import TlvReader

    reader = TlvReader(on_error="log")
    t0 = time.monotonic()
    sent = 0
    with open(path, "rb") as f:
        while True:
            data = f.read(chunk)
            if not data:
                break
            if pace_baud:
                due = t0 + (sent + len(data)) * 10 / pace_baud
                delay = due - time.monotonic()
                if delay > 0:
                    sleep(delay)
            sent += len(data)
            now = time.time()
            for pkt in reader.feed(data):
                yield pkt.radar_frame(now)
        for pkt in reader.finish():
            yield pkt.radar_frame(time.time())
    if stats_out is not None:
        stats_out.update(reader.stats.as_dict())


def compare_fused(recorded: list[dict], replayed: list[dict], atol: float = 1e-6) -> dict[str, Any]:
    """Match fused results by seq and compare them without wall-clock fields."""
    from mmatch.edge.node import comparable

    def key(m: dict) -> tuple[int, int]:  # seq restarts with each run; the stamp does not
        return int(m["seq"]), logschema.stamp_key(float(m["stamp"]))

    rep = {key(m): comparable(m) for m in replayed}
    same, differ, missing = 0, [], []
    for m in recorded:
        r = rep.get(key(m))
        if r is None:
            missing.append(m["seq"])
        elif _close(comparable(m), r, atol):
            same += 1
        else:
            differ.append(m["seq"])
    # a replayed result the live run never logged, inside the span it logged (after its last
    # record a cut log may lack the result of a frame it still holds)
    last = max((float(m["stamp"]) for m in recorded), default=float("-inf"))
    seen = {key(m) for m in recorded}
    extra = [m["seq"] for m in replayed if key(m) not in seen and float(m["stamp"]) <= last]
    return {"recorded": len(recorded), "replayed": len(replayed), "same": same,
            "differ": differ, "missing": missing, "extra": extra,
            "match": bool(recorded) and not differ and not missing and not extra}


def load_eval_frames(path: str | Path) -> list[dict]:
    """The tracked per-frame rows of `mmatch eval --sequences --json FILE` (FILE or its
    FILE.frames.json); ParseError naming the file when it holds none."""
    path = Path(path)
    if not path.name.endswith(".frames.json"):
        sibling = path.with_name(path.name[:-len(".json")] + ".frames.json") if path.name.endswith(".json") else None
        if sibling is not None and sibling.exists():
            path = sibling
    try:
        data = json.loads(path.read_text())
        rows = data["tracked"]
        if not isinstance(rows, list):
            raise TypeError("tracked is not a list")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ParseError(f"{path}: not the frames of `mmatch eval --sequences` ({exc})") from exc
    return [r for r in rows if isinstance(r, dict) and "rejected" not in r]


def _same(a: Any, b: Any) -> bool:
    """Exact equality of JSON values, NaN and null alike (a non-finite number is null on the wire)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    nan = lambda v: v is None or (isinstance(v, float) and v != v)  # noqa: E731
    if nan(a) or nan(b):
        return nan(a) and nan(b)
    return a == b


def compare_eval(fused: list[dict], rows: list[dict]) -> dict[str, Any]:
    """Replayed fused messages against `mmatch eval --sequences` tracked rows of the same drive,
    frame by frame (joined on the Ego's capture stamp), exactly: the status, the first CAV's
    T_ego_cav, confidence and covariance, the objects with their track ids and the tracks.

    The drive is the sequence of `rows` sharing most stamps with `fused`; its frames without a
    replayed message are "missing". Returns {"sequence", "frames", "same", "differ": [{"frame",
    "fields"}], "missing": [frame, ...], "match"}."""
    by_stamp = {logschema.stamp_key(float(m["stamp"])): m for m in fused}
    seqs: dict[str, list[dict]] = {}
    for r in rows:
        seqs.setdefault(str(r.get("sequence")), []).append(r)
    if not seqs:
        return {"sequence": None, "frames": 0, "same": 0, "differ": [], "missing": [], "match": False}
    name = max(sorted(seqs), key=lambda s: sum(logschema.stamp_key(float(r["stamp"])) in by_stamp for r in seqs[s]))
    same, differ, missing = 0, [], []
    for r in sorted(seqs[name], key=lambda r: r["frame"]):
        m = by_stamp.get(logschema.stamp_key(float(r["stamp"])))
        if m is None:
            missing.append(r["frame"])
            continue
        cav = m["cavs"][0] if m.get("cavs") else {}
        pairs = {"status": (m["status"], r["status"]),
                 "T_ego_cav": (cav.get("T_ego_cav"), r.get("T_ego_cav")),
                 "confidence": (cav.get("confidence"), r.get("confidence")),
                 "covariance": (cav.get("covariance"), r.get("covariance")),
                 "objects": (m.get("objects"), r.get("fused_objects")),
                 "tracks": (m.get("tracks"), r.get("tracks"))}
        bad = sorted(k for k, (a, b) in pairs.items() if not _same(a, b))
        if bad:
            differ.append({"frame": r["frame"], "fields": bad})
        else:
            same += 1
    return {"sequence": name, "frames": len(seqs[name]), "same": same, "differ": differ, "missing": missing,
            "match": same == len(seqs[name])}


def _close(a: Any, b: Any, atol: float) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], atol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, atol) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        try:
            return abs(float(a) - float(b)) <= atol * max(1.0, abs(float(a)))
        except (TypeError, ValueError):
            return False
    return a == b


def _check_capture(path: Path) -> None:
    """ParseError unless `path` looks like a raw TI UART capture (the magic word in its first MiB)."""
    from mmatch.drivers.ti.header import MAGIC

    try:
        with open(path, "rb") as f:
            head = f.read(1 << 20)
    except OSError as exc:
        raise ParseError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if MAGIC not in head:
        raise ParseError(f"{path}: neither an MCAP log nor a raw TI UART capture "
                         f"({'empty' if not head else 'no TI magic word in its first MiB'})")


def _replay_config(log_path: str | Path, is_log: bool, config_path: str | None, sets: list[str]) -> Any:
    import tomllib

    from mmatch.edge import config as cfgmod

    overrides = cfgmod.parse_overrides(sets)
    if config_path:
        data = cfgmod.read_table(config_path)
    else:
        text = log_config_text(log_path) if is_log else None
        data = tomllib.loads(text) if text else {"vehicle": {"id": "replay", "role": "cav"}}
    data = cfgmod.merge(data, {"log": {"dir": ""}})  # never write into the log being read
    data = cfgmod.merge(data, overrides)
    return cfgmod.from_dict(data, source=str(config_path or log_path))


def replay(path: str | Path, *, config_path: str | None = None, sets: list[str] = (), fast: bool = False,
           speed: float = 1.0, process: bool = True, publish: bool = False, log_dir: str | None = None,
           fused_out: str | None = None, frames_out: str | None = None,
           compare: bool = False, compare_eval_path: str | None = None) -> dict[str, Any]:
    """Replay a log or capture through a `Node`; returns a summary dict.

    A log replays its own frames and the shared frames it received, in the recorded order;
    a raw UART capture yields radar frames (no camera) through the TI streaming reader.
    compare: against the fused results the log holds; compare_eval_path: against the tracked
    frames of `mmatch eval --sequences` on the files the log was recorded from (`compare_eval`).
    """
    import contextlib

    from mmatch.edge import config as cfgmod
    from mmatch.edge.node import Node
    from mmatch.edge.pipeline import default_pipeline
    from mmatch.edge.recorder import Recorder
    from mmatch.edge.sources.base import default_camera
    from mmatch.edge.transport import Transport
    from mmatch.errors import DecodeError, MMatchError

    path = Path(path)
    if not path.exists():
        raise ParseError(f"{path}: no such file or folder")
    is_log = path.is_dir() or logreader.is_mcap(path)
    if not is_log:
        _check_capture(path)
    cfg = _replay_config(path, is_log, config_path, list(sets))
    camera, height = default_camera(), cfg.radar.height_m
    if is_log:
        meta = log_metadata(path).get("camera")
        if meta:
            camera, height = logschema.camera_from_meta(meta)
    summary: dict[str, Any] = {"log": str(path), "kind": "mcap" if is_log else "uart-capture",
                               "role": cfg.vehicle.role, "vehicle": cfg.vehicle.id}
    fused: list[dict] = []
    recorded: list[dict] = []
    frames_json: list[dict] = []
    rx_bad = 0
    report = logreader.LogReport()
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        recorder = None
        if log_dir:
            recorder = stack.enter_context(Recorder(
                cfgmod.from_dict(cfgmod.merge(cfgmod.to_dict(cfg), {"log": {"dir": log_dir}})).log,
                prefix=f"replay-{cfg.vehicle.id}", config_text=cfgmod.to_toml(cfg)))
            recorder.set_metadata("camera", logschema.camera_to_meta(camera, height))
        transport = stack.enter_context(Transport(cfg.zenoh)) if publish else None
        signer = None
        if publish:  # results published "as live" are signed as live; the inputs were verified live
            from mmatch.edge.auth import identity
            signer = identity(cfg, need_trust=False).signer
        node = None
        pipeline = default_pipeline(need_fuse=cfg.is_ego, track_max_age_s=cfg.ego.track_max_age_s,
                                    confidence_threshold=cfg.ego.confidence_threshold) if process else None

        def fresh_node() -> Node:
            n = Node(cfg, pipeline, camera, height, publish=transport.put if transport else None,
                     recorder=recorder, signer=signer)
            n.on_result = fused.append
            n.replay_skips = budget_skips
            return n

        budget_skips: dict[tuple[int, int], list[str]] = {}
        if process and is_log:
            budget_skips = recorded_budget_skips(path)
        if process:
            node = fresh_node()
        pacer = Pacer(fast, speed)
        if is_log:
            events: Iterator[Event] = log_events(path, report)
        else:
            cap_stats: dict = {}
            baud = None if fast else int(cfg.radar.baudrate * speed)
            events = (Event("frame", int(f.host_time * 1e9), frame=SensorFrame(
                seq=i + 1, stamp=f.stamp, points=np.asarray(f.points, np.float32),
                boxes=np.zeros((0, 6), np.float32), features=np.zeros((0, 32), np.float32),
                frame_number=f.frame_number, host_time=f.host_time))
                for i, f in enumerate(capture_frames(path, pace_baud=baud, stats_out=cap_stats)))
        n_frames = 0
        runs = 1
        for ev in events:
            if ev.kind == "fused":
                recorded.append(ev.msg)
                continue
            if ev.kind == "run":
                runs += 1
                if node is not None:
                    node = fresh_node()
                continue
            if is_log:
                pacer.wait(ev.log_time_ns)
            if ev.kind == "frame":
                n_frames += 1
                f = ev.frame
                if frames_out:
                    frames_json.append({"seq": f.seq, "frame_number": f.frame_number,
                                        "points": np.asarray(f.points, np.float64).tolist()})
                if node is not None:
                    try:
                        node.process(f)
                    except MMatchError as exc:
                        log.warning("frame %d: %s", f.seq, exc)
            elif ev.kind == "rx" and node is not None:
                try:
                    node.on_shared(ev.vehicle, ev.data)
                except DecodeError:
                    rx_bad += 1
    summary.update(runs=runs, frames=n_frames, fused_results=len(fused), rx_rejected=rx_bad,
                   seconds=round(time.perf_counter() - t0, 3),
                   truncated=report.truncated, corrupt=report.corrupt, files=report.files)
    if not is_log:
        summary["reader"] = cap_stats
    if node is not None:
        summary["node"] = node.summary()
        statuses: dict[str, int] = {}
        for m in fused:
            statuses[m["status"]] = statuses.get(m["status"], 0) + 1
        summary["status_counts"] = statuses
    if compare:
        summary["compare"] = compare_fused(recorded, fused)
    if compare_eval_path:
        summary["compare_eval"] = compare_eval(fused, load_eval_frames(compare_eval_path))
    if fused_out:
        with open(fused_out, "w") as f:
            for m in fused:
                f.write(json.dumps(m) + "\n")
    if frames_out:
        with open(frames_out, "w") as f:
            json.dump({"frames": len(frames_json), "frame_numbers": [x["frame_number"] for x in frames_json],
                       "points": [x["points"] for x in frames_json]}, f)
    return summary
