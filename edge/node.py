"""One vehicle's per-frame processing, the part live runs and replays share.

`Node.process(frame)` runs the CAV side on the vehicle's own sensor frame
(process_view -> encode -> publish) and, for an Ego, pairs the result with the CAV
frame closest in capture time within `ego.pair_tolerance_s` from each CAV, fuses, and
publishes the fused result (`mmatch/v1/<id>/fused`, JSON). `Node.on_shared(vehicle,
payload)` takes a received shared frame.

Trust (edge/auth.py): live, every received frame goes through a `Verifier` (signature by a
fleet key, sequence number, stamp window, caps; refusals counted by reason) and everything
this vehicle publishes is signed by its `Signer`. A replay reads frames the live run had
verified before logging them, so it checks their structure and caps only.

"Every CAV" mode (`ego.cavs = []`) takes any vehicle of the trust file, at most
`ego.max_links` at once; a CAV silent for `ego.link_expire_s` is forgotten. Live, fusion
starts no further CAV once fusing a frame has taken `ego.frame_budget_s` (the first CAV is
always fused; the skipped ones are named in the message and counted; a replay leaves out the
same ones).

Link loss: a CAV whose newest frame is older (in capture time) than `ego.link_timeout_s`
is flagged lost; the Ego then publishes its own perception with `single_vehicle: true`
and fuses again as soon as frames return. Everything that decides a result is judged on
capture stamps, not the wall clock, and the inputs are logged in the order the decision
saw them, so replaying a log through a Node reproduces the live results.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mmatch import codec
from mmatch.edge import keys, logschema
from mmatch.edge.auth import Rejected, Sequence, Signer, Verifier, limits_of, seal_message
from mmatch.edge.config import VehicleConfig
from mmatch.edge.logschema import SensorFrame
from mmatch.edge.pipeline import Pipeline
from mmatch.errors import DecodeError
from mmatch.types import CameraModel

log = logging.getLogger(__name__)

PublishFn = Callable[[str, bytes], None]


@dataclass
class LinkState:
    """What the Ego knows about one CAV's link."""

    up: bool = False
    newest_stamp: float = -np.inf
    frames: int = 0
    gaps: int = 0
    ever_up: bool = False
    confidence: float | None = None   # of the latest fusion with this CAV (null: no estimate)
    ambiguity: float | None = None
    turn: int = -1                    # when it was last fused, counted in fusions (-1: never)


@dataclass
class NodeCounters:
    frames: int = 0
    published_shared: int = 0
    fused: int = 0          # at least one CAV frame fused
    paired: int = 0         # at least one CAV frame given to fuse (fused or no-estimate)
    single: int = 0         # own perception only
    no_estimate: int = 0
    rx: int = 0
    rx_rejected: dict[str, int] = field(default_factory=lambda: collections.Counter())
    budget_skipped: int = 0
    links_expired: int = 0


def _jsonable_matrix(T: Any) -> list | None:
    return None if T is None else np.asarray(T, dtype=np.float64).reshape(4, 4).tolist()


def _number(x: Any) -> float | None:
    """A finite float, or None (JSON null) for NaN, infinity or no value."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _covariance(c: Any) -> list | None:
    """A 3x3 (x m, y m, yaw rad) covariance as nested lists, non-finite entries as null."""
    if c is None:
        return None
    a = np.asarray(c, dtype=np.float64)
    if a.shape != (3, 3):
        return None
    return [[_number(v) for v in row] for row in a]


def _finite(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def dumps(msg: dict) -> bytes:
    """Compact JSON of a message; NaN and infinity become null (JSON has neither)."""
    try:
        return json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
    except ValueError:
        return json.dumps(_finite(msg), separators=(",", ":"), allow_nan=False).encode()




class Node:
    """The per-frame CAV/Ego logic of one vehicle (thread-safe)."""

    def __init__(self, cfg: VehicleConfig, pipeline: Pipeline, camera: CameraModel,
                 radar_height: float, *, publish: PublishFn | None = None, recorder: Any = None,
                 wait_s: float = 0.0, clock: Callable[[], float] = time.time,
                 signer: Signer | None = None, verifier: Verifier | None = None,
                 budget_s: float | None = None) -> None:
        self.cfg = cfg
        self.id = cfg.vehicle.id
        self.pipeline = pipeline
        self.camera = camera
        self.radar_height = float(radar_height)
        self.publish = publish
        self.recorder = recorder
        self.wait_s = wait_s
        self.clock = clock
        self.signer = signer
        self.verifier = verifier
        self.budget_s = budget_s
        #: replay: {(own seq, stamp ns): CAVs the live run left out for its budget}, redone as live
        self.replay_skips: dict[tuple[int, int], list[str]] | None = None
        self.limits = limits_of(cfg)
        self._seq = {"shared": Sequence(), "fused": Sequence()}
        self.counters = NodeCounters()
        self.links: dict[str, LinkState] = {c: LinkState() for c in cfg.ego.cavs}
        self._turns = 0                   # fusions so far (LinkState.turn)
        self._inbox: dict[str, collections.deque] = {}
        self._cond = threading.Condition()
        self.last_result: dict | None = None
        self.on_result: Callable[[dict], None] | None = None

    def warm_up(self) -> None:
        """Run the pipeline once on a synthetic frame so the first real frame is not late
        (lazy imports and first-call set-up cost about a second)."""
        rng = np.random.default_rng(0)
        pts = np.c_[rng.uniform(-10, 10, (60, 1)), rng.uniform(5, 40, (60, 1)),
                    rng.uniform(-1, 1, (60, 1)), rng.uniform(-3, 3, (60, 1)),
                    rng.uniform(5, 30, (60, 1))].astype(np.float32)
        box = np.array([[600, 300, 700, 400, 0.9, 20.0]], np.float32)
        feats = np.full((1, 32), 1 / 16, np.float32)
        t0 = time.perf_counter()
        try:
            own, _ = self.pipeline.process_view(pts, box, feats, self.camera, self.radar_height, 0.0,
                                                sender=self.id, seq=0)
            self.pipeline.decode(self.pipeline.encode(own))
            if self.cfg.is_ego:
                self.pipeline.fuse(own, own)
                self.pipeline.fuse(own, None)
        except Exception as exc:  # warm-up is best effort; real frames report real errors
            log.debug("warm-up: %s", exc)
        log.info("pipeline warm-up took %.0f ms", (time.perf_counter() - t0) * 1e3)

    # ------------------------------------------------------------------ input
    def on_shared(self, vehicle: str, payload: bytes) -> None:
        """A shared frame from `vehicle` (raises DecodeError for a bad one, after counting).

        Live (a verifier is set): every check of edge/auth.py, cheap ones first. Replay (no
        verifier): the frames were verified live before they were logged; structure and caps.
        """
        if vehicle == self.id:
            return
        rejected = self.counters.rx_rejected
        if self.cfg.ego.cavs and vehicle not in self.cfg.ego.cavs:
            rejected["foreign"] += 1
            return
        if self.verifier is not None:
            try:
                frame = self.verifier.open_frame(vehicle, payload, self.pipeline.decode)
            except Rejected as exc:
                rejected[exc.reason] += 1
                raise
        else:
            try:
                codec.header(payload, self.limits)
                frame = self.pipeline.decode(payload)
                codec.check_range(frame, self.limits)
            except codec.OverCaps:
                rejected["caps"] += 1
                raise
            except DecodeError:
                rejected["malformed"] += 1
                raise
            if frame.sender != vehicle:
                rejected["sender_mismatch"] += 1
                raise DecodeError(f"frame from {frame.sender!r} published under {vehicle!r}")
        with self._cond:
            if (not self.cfg.ego.cavs and vehicle not in self.links and vehicle not in self._inbox
                    and len(set(self.links) | set(self._inbox)) >= self.cfg.ego.max_links):
                rejected["link_cap"] += 1
                raise Rejected("link_cap", f"{vehicle!r}: already {self.cfg.ego.max_links} CAVs")
            if self.recorder is not None:  # the wire record and its Foxglove views (encoded later)
                for topic, record in logschema.shared_records(logschema.shared_topic(vehicle), payload, frame):
                    self.recorder.write(topic, record, stamp=frame.stamp)
            box = self._inbox.get(vehicle)
            if box is None:
                box = self._inbox[vehicle] = collections.deque(maxlen=self.cfg.ego.history)
            box.append(frame)
            self.counters.rx += 1
            self._cond.notify_all()

    # ------------------------------------------------------------------ per frame
    def _log_frame(self, frame: SensorFrame) -> None:
        if self.recorder is not None:
            self.recorder.write(logschema.POINTS, logschema.points_message(frame.points, frame.stamp, self.id),
                                stamp=frame.stamp)
            self.recorder.write(logschema.FRAME, logschema.frame_to_json(frame), stamp=frame.stamp)

    def process(self, frame: SensorFrame) -> dict | None:
        """Run one own sensor frame through the pipeline; the fused message for an Ego."""
        self.counters.frames += 1
        lag = {"start": (self.clock() - frame.stamp) * 1e3}
        own, timings = self.pipeline.process_view(
            frame.points, frame.boxes, frame.features, self.camera, self.radar_height, frame.stamp,
            sender=self.id, seq=frame.seq)
        if self.cfg.is_cav:
            if self.signer is not None:  # wire seq: increasing across restarts (auth.Sequence)
                sent = dataclasses.replace(own, seq=self._seq["shared"].next())
                data = self.pipeline.encode(sent, self.signer)
            else:
                sent = own
                data = self.pipeline.encode(own)
            if self.publish is not None:
                self.publish(keys.shared(self.id), data)
                self.counters.published_shared += 1
            if not self.cfg.is_ego:
                self._log_frame(frame)
            if self.recorder is not None:
                for topic, record in logschema.shared_records(logschema.shared_topic(None), data, sent):
                    self.recorder.write(topic, record, stamp=frame.stamp)
        if not self.cfg.is_ego:
            return None
        lag["processed"] = (self.clock() - frame.stamp) * 1e3
        choice = self._pair(frame)
        lag["paired"] = (self.clock() - frame.stamp) * 1e3
        timings = {**timings, **{f"lag:{k}": v for k, v in lag.items()}}
        return self._fuse(frame, own, timings, choice)

    def _wanted(self, stamp: float) -> bool:
        """True while some live CAV may still deliver a frame closer to `stamp`."""
        horizon = stamp - self.cfg.ego.pair_tolerance_s / 2
        for name, link in self.links.items():
            if not link.up:
                continue
            box = self._inbox.get(name)
            if not box or box[-1].stamp < horizon:
                return True
        return False

    def _pair(self, frame: SensorFrame) -> dict[str, Any]:
        """The CAV frame closest in capture time to `frame`, per CAV (logged at decision)."""
        tol = self.cfg.ego.pair_tolerance_s
        if self.verifier is not None:  # a lagging loop still takes the frames it can pair with
            self.verifier.pairing_horizon = frame.stamp - tol
        with self._cond:
            if self.wait_s > 0:
                # deadline on the shared clock: own capture + wait_s keeps the latency budget
                deadline = frame.stamp + self.wait_s
                while self._wanted(frame.stamp):
                    left = deadline - self.clock()
                    if left <= 0:
                        break
                    self._cond.wait(left)
            self._log_frame(frame)  # the decision point: replay sees exactly these inputs
            self._expire(frame.stamp)
            choice: dict[str, Any] = {}
            for name in sorted(set(self._inbox) | set(self.links)):
                link = self.links.setdefault(name, LinkState())
                box = self._inbox.get(name, ())
                newest = max((f.stamp for f in box), default=-np.inf)
                up = newest >= frame.stamp - self.cfg.ego.link_timeout_s
                if up != link.up:
                    if up:
                        log.info("link to %s %s", name, "resumed" if link.ever_up else "up")
                        link.ever_up = True
                    else:
                        link.gaps += 1
                        log.warning("link to %s lost (newest frame %.3f s before own frame)",
                                    name, frame.stamp - newest)
                    link.up = up
                link.newest_stamp = newest
                best = min(box, key=lambda f: abs(f.stamp - frame.stamp), default=None)
                if best is not None and abs(best.stamp - frame.stamp) <= tol and up:
                    choice[name] = best
            return choice

    def _expire(self, stamp: float) -> None:
        """Every-CAV mode: forget CAVs silent for ego.link_expire_s (capture time). Under _cond."""
        if self.cfg.ego.cavs:
            return
        for name in sorted(set(self.links) | set(self._inbox)):
            box = self._inbox.get(name)
            newest = box[-1].stamp if box else self.links[name].newest_stamp
            if newest < stamp - self.cfg.ego.link_expire_s:
                self.links.pop(name, None)
                self._inbox.pop(name, None)
                self.counters.links_expired += 1
                log.info("link to %s expired (silent for %.0f s)", name, stamp - newest)

    def _fuse(self, frame: SensorFrame, own: Any, timings: dict[str, float],
              choice: dict[str, Any]) -> dict:
        cavs = []
        objects: list[np.ndarray] = []
        fuse_ms: dict[str, float] = {}
        results = []
        skipped: list[str] = []
        t_start = time.perf_counter()
        live_skips = None
        if self.replay_skips is not None:
            live_skips = self.replay_skips.get((int(frame.seq), logschema.stamp_key(frame.stamp)), [])
        # the CAV fused least recently goes first (then by name): under a budget that keeps
        # running out, the CAVs take turns instead of the same ones being left out every frame
        waited = sorted(choice, key=lambda n: (self.links[n].turn if n in self.links else -1, n))
        for name in waited:
            other = choice[name]
            # the first CAV is always fused: a late frame costs latency, never the estimate
            over = (results and self.budget_s is not None
                    and time.perf_counter() - t_start > self.budget_s)
            if (over and live_skips is None) or (live_skips is not None and name in live_skips):
                skipped.append(name)
                continue
            t0 = time.perf_counter()
            res = self.pipeline.fuse(own, other)
            fuse_ms[name] = (time.perf_counter() - t0) * 1e3
            results.append((name, other, res))
            cavs.append({"id": name, "seq": int(other.seq), "stamp": float(other.stamp),
                         "dt": float(other.stamp - frame.stamp), "status": res.status,
                         "reason": res.reason, "T_ego_cav": _jsonable_matrix(res.T_ego_cav),
                         "pairs": np.asarray(res.pairs).reshape(-1, 2).astype(int).tolist(),
                         "confidence": _number(getattr(res, "confidence", None)),
                         "covariance": _covariance(getattr(res, "covariance", None)),
                         "ambiguity": _number(getattr(res, "ambiguity", None))})
            link = self.links.get(name)
            if link is not None:
                link.confidence = cavs[-1]["confidence"]
                link.ambiguity = cavs[-1]["ambiguity"]
                self._turns += 1
                link.turn = self._turns
        if skipped:
            self.counters.budget_skipped += len(skipped)
            log.warning("frame %d: over the time budget, not fused with %s", frame.seq,
                        ", ".join(skipped))
        from mmatch.ego.track.objects import object_rows, track_record

        fused = [r for r in results if r[2].status == "fused"]
        tracked = None
        if self.pipeline.track_objects is not None:  # once per frame, after every CAV
            tracked = self.pipeline.track_objects(own, [(other, r) for _, other, r in fused])
        if fused:
            status = "fused"
            first = np.asarray(fused[0][2].objects, np.float64).reshape(-1, 4)
            objects.append(object_rows(first, tracked, fused[0][1].sender))
            for _, other, r in fused[1:]:
                o = np.asarray(r.objects, np.float64).reshape(-1, 4)
                objects.append(object_rows(o[o[:, 2] == 1], tracked, other.sender))
        else:
            single = self.pipeline.fuse(own, None)
            status = "no-estimate" if results else "single"
            objects.append(object_rows(np.asarray(single.objects, np.float64).reshape(-1, 4), tracked, ""))
        c = self.counters
        c.fused += bool(fused)
        c.paired += bool(results)
        c.single += not results
        c.no_estimate += bool(results) and not fused
        obj = np.concatenate(objects) if objects else np.zeros((0, 4 if tracked is None else 5))
        msg = {
            "vehicle": self.id, "seq": int(frame.seq), "stamp": float(frame.stamp),
            "status": status, "single_vehicle": not fused,
            "links": {n: ("up" if s.up else "lost") for n, s in sorted(self.links.items())},
            "gap": any(not s.up for s in self.links.values()),
            "cavs": cavs,
            "objects": np.round(obj, 6).tolist(),
            "timings_ms": {**{k: float(v) for k, v in timings.items()},
                           **{f"fuse:{k}": v for k, v in fuse_ms.items()}},
        }
        if tracked is not None:
            msg["tracks"] = [track_record(t, frame.stamp) for t in tracked.tracks]
        if skipped:
            msg["budget_skipped"] = skipped
        msg["latency_ms"] = (self.clock() - frame.stamp) * 1e3
        if self.publish is not None:
            data = dumps(msg)
            if self.signer is not None:
                data = seal_message(self.signer, "fused", data, self._seq["fused"].next(), frame.stamp)
            self.publish(keys.fused(self.id), data)
        if self.recorder is not None:
            self.recorder.write(logschema.FUSED, msg, stamp=frame.stamp)
            for topic, record in logschema.fused_records(msg, self.radar_height):
                self.recorder.write(topic, record, stamp=frame.stamp)
        self.last_result = msg
        if self.on_result is not None:
            self.on_result(msg)
        if self.pipeline.idle is not None:   # after the result is out: costs the next frame nothing it needs
            self.pipeline.idle()
        return msg

    def summary(self) -> dict[str, Any]:
        c = self.counters
        return {"frames": c.frames, "published_shared": c.published_shared, "fused": c.fused,
                "paired": c.paired, "single": c.single,
                "no_estimate": c.no_estimate, "rx": c.rx, "rx_rejected": dict(c.rx_rejected),
                "budget_skipped": c.budget_skipped, "links_expired": c.links_expired,
                "links": {n: {"up": s.up, "gaps": s.gaps, "confidence": s.confidence,
                              "ambiguity": s.ambiguity} for n, s in self.links.items()},
                "camera_depth_scale": _depth_scale(self.pipeline),
                "input_repairs": _input_repairs(self.pipeline)}


def _depth_scale(pipeline: Pipeline) -> float | None:
    """The factor the CAV side puts on this camera's box depths (its calibration to the radar,
    mmatch/cav/depth_scale.py); None when the pipeline keeps none."""
    scale = getattr(getattr(pipeline.process_view, "depth", None), "scale", None)
    return None if scale is None else round(float(scale), 4)


def _input_repairs(pipeline: Pipeline) -> dict[str, int] | None:
    """What the CAV side repaired in this vehicle's own inputs so far, by kind (returns dropped
    or thinned, box depths from the size prior, descriptors rescaled: mmatch/cav/process.py
    REPAIRS); None when the pipeline counts none."""
    repairs = getattr(pipeline.process_view, "repairs", None)
    return None if repairs is None else {k: int(v) for k, v in repairs.items()}


def comparable(msg: dict) -> dict:
    """A fused message without its wall-clock fields (latency, stage timings)."""
    return {k: v for k, v in msg.items() if k not in ("latency_ms", "timings_ms")}
