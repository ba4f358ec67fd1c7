"""The live vehicle loop: reader threads per sensor, bounded queues, the per-frame Node.

One thread per sensor reads its source into a bounded queue that keeps the newest items
(a slow loop drops old frames, counted; a lossless replay source blocks instead). The
main thread takes each radar frame, attaches the camera detections closest in time,
and hands it to the `Node`. A sensor error (unplugged serial port, camera gone) is logged
and counted; the reader closes the source, waits `reconnect_s` and opens it again, while
the rest keeps running. Health goes to the log, to systemd ($NOTIFY_SOCKET) and to Zenoh.
"""

from __future__ import annotations

import collections
import gc
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from mmatch.edge import keys, logschema
from mmatch.edge.auth import Identity, Sequence, seal_message, verifier_for
from mmatch.edge.config import VehicleConfig
from mmatch.edge.health import Notifier, RateCounter, format_status, watchdog_interval
from mmatch.edge.logschema import SensorFrame
from mmatch.edge.node import Node, dumps
from mmatch.edge.pipeline import Pipeline
from mmatch.edge.sources.base import CameraSource, EndOfStream, RadarSource
from mmatch.edge.sources.replay import RECORDED_DETECTIONS
from mmatch.edge.transport import KeepNewest
from mmatch.errors import DeviceError, MMatchError
from mmatch.types import Detections, RadarFrame

log = logging.getLogger(__name__)


class _LosslessQueue:
    """A blocking bounded queue with the KeepNewest reading interface (for replay)."""

    def __init__(self, maxlen: int, stop: threading.Event) -> None:
        self._q: queue.Queue = queue.Queue(maxlen)
        self._stop = stop
        self.dropped = 0

    def put(self, item: Any) -> None:
        while not self._stop.is_set():
            try:
                self._q.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def get(self, timeout: float | None = None) -> Any:
        try:
            return self._q.get(timeout=timeout)
        except queue.Empty:
            return None

    def __len__(self) -> int:
        return self._q.qsize()


class CameraHistory:
    """The last few detections; picks the one closest in time to a radar stamp."""

    def __init__(self, maxlen: int = 8) -> None:
        self._items: collections.deque[Detections] = collections.deque(maxlen=maxlen)
        self._cond = threading.Condition()

    def put(self, det: Detections) -> None:
        with self._cond:
            self._items.append(det)
            self._cond.notify_all()

    def _best(self, stamp: float) -> Detections | None:
        return min(self._items, key=lambda d: abs(d.stamp - stamp), default=None)

    def closest(self, stamp: float, tolerance: float, wait_s: float = 0.0) -> Detections | None:
        """Detections closest in time to `stamp` within `tolerance` s; waits up to `wait_s`
        for one at least as new as `stamp` (an image usually lands just after its radar frame)."""
        deadline = time.monotonic() + wait_s
        with self._cond:
            while True:
                newest = self._items[-1].stamp if self._items else -np.inf
                left = deadline - time.monotonic()
                if newest >= stamp or left <= 0:
                    break
                self._cond.wait(left)
            best = self._best(stamp)
        if best is None or not abs(best.stamp - stamp) <= tolerance:
            return None
        return best


class SensorReader(threading.Thread):
    """Reads one source forever, reopening it after errors, into `sink`."""

    def __init__(self, name: str, source: RadarSource | CameraSource, sink: Callable[[Any], None],
                 stop: threading.Event, reconnect_s: float, timeout: float = 0.2) -> None:
        super().__init__(name=f"reader-{name}", daemon=True)
        self.sensor = name
        self.source = source
        self.sink = sink
        self.stop_event = stop
        self.reconnect_s = reconnect_s
        self.timeout = timeout
        self.frames = RateCounter()
        self.errors = 0
        self.reopens = 0
        self.ended = threading.Event()
        self.opened = False

    def run(self) -> None:
        while not self.stop_event.is_set():
            try:
                if not self.opened:
                    self.source.open()
                    self.opened = True
                    if self.reopens or self.errors:
                        log.info("%s: reopened after %d error(s)", self.sensor, self.errors)
                item = self.source.read(self.timeout)
            except EndOfStream:
                log.info("%s: end of stream", self.sensor)
                self.ended.set()
                break
            except (DeviceError, OSError, MMatchError) as exc:
                self._fault(exc)
                continue
            except Exception as exc:  # a backend bug must not end the service
                log.exception("%s: unexpected error", self.sensor)
                self._fault(exc)
                continue
            if item is not None:
                self.frames.add()
                self.sink(item)
        self._close()

    def _fault(self, exc: BaseException) -> None:
        self.errors += 1
        log.warning("%s: %s; reopening in %.1f s", self.sensor, exc, self.reconnect_s)
        self._close()
        self.reopens += 1
        self.stop_event.wait(self.reconnect_s)

    def _close(self) -> None:
        try:
            self.source.close()
        except Exception as exc:
            log.debug("%s: close failed: %s", self.sensor, exc)
        self.opened = False


class VehicleLoop:
    """Sensors -> Node -> Zenoh/log, until `stop` is set (or a finite source ends)."""

    def __init__(self, cfg: VehicleConfig, radar: RadarSource, camera: CameraSource,
                 pipeline: Pipeline | None, *, transport: Any = None, recorder: Any = None,
                 notifier: Notifier | None = None, process: bool = True,
                 identity: Identity | None = None) -> None:
        self.cfg = cfg
        self.radar = radar
        self.camera = camera
        self.transport = transport
        self.recorder = recorder
        self.notifier = notifier or Notifier()
        self.process = process
        self.identity = identity
        self._health_seq = Sequence()
        self.stop = threading.Event()
        lossless = radar.lossless
        # recording only does little per frame: a deep queue keeps bursts (several frames in
        # one serial read); live processing keeps the newest `queue_size` frames.
        depth = cfg.loop.queue_size if process else max(cfg.loop.queue_size, 256)
        self.radar_q = _LosslessQueue(depth, self.stop) if lossless else KeepNewest(depth)
        self.cam_hist = CameraHistory()
        self.drops: collections.Counter = collections.Counter()
        self.readers: list[SensorReader] = []
        self.seq = 0
        self.rates = {"radar": RateCounter(), "frames": RateCounter()}
        if process and cfg.is_cav:
            self.rates["shared"] = RateCounter()
        if process and cfg.is_ego:
            self.rates["fused"] = RateCounter()
        self.node: Node | None = None
        if process:
            assert pipeline is not None
            publish = self._publish if transport is not None else None
            height = getattr(radar, "radar_height", cfg.radar.height_m)
            signer = identity.signer if identity is not None else None
            # a source with a clock of its own (scene files keep their drive's time) sets the
            # time that waiting, link states and the stamp window are judged on
            clock = getattr(radar, "clock", None) or time.time
            verifier = None
            if identity is not None and identity.trust is not None:
                verifier = verifier_for(cfg, identity.trust, clock=clock)
            self.node = Node(cfg, pipeline, camera.camera, height, publish=publish, recorder=recorder,
                             wait_s=cfg.ego.wait_s, clock=clock, signer=signer, verifier=verifier,
                             budget_s=cfg.ego.frame_budget_s)
            self.node.on_result = self._on_result
        if recorder is not None and hasattr(camera, "camera"):
            height = getattr(radar, "radar_height", cfg.radar.height_m)
            recorder.set_metadata("camera", logschema.camera_to_meta(camera.camera, height))
        if recorder is not None and cfg.log.raw:
            topic = radar.raw_topic
            radar.raw_sink = lambda data: recorder.write(topic, data)

    def _on_result(self, msg: dict) -> None:
        if msg["status"] == "fused":
            self.rates["fused"].add()

    def _publish(self, key: str, data: bytes) -> None:
        self.transport.put(key, data)
        if "shared" in self.rates and key.endswith("/shared"):
            self.rates["shared"].add()

    # ------------------------------------------------------------------ run
    def run(self) -> int:
        """Run until stopped; returns 0. Call from the main thread."""
        cfg = self.cfg
        if self.transport is not None and self.node is not None and cfg.is_ego:
            if cfg.ego.cavs and len(cfg.ego.cavs) == 1:
                keyexpr = keys.shared(cfg.ego.cavs[0])
            else:
                keyexpr = keys.all_of("shared")
            self.transport.subscribe(keyexpr, "shared", self.node.on_shared,
                                     vehicles=list(cfg.ego.cavs) or None,
                                     max_payload=self.node.limits.max_frame_bytes)
        if self.node is not None:
            self.node.warm_up()
        gc.collect()
        gc.freeze()  # start-up objects leave the collector's view: shorter pauses per frame
        readers = [SensorReader("radar", self.radar, self.radar_q.put, self.stop, cfg.radar.reconnect_s,
                                cfg.radar.read_timeout_s)]
        if cfg.camera.source not in ("none",):
            readers.append(SensorReader("camera", self.camera, self.cam_hist.put, self.stop,
                                        cfg.camera.reconnect_s))
        self.readers = readers
        for r in readers:
            r.start()
        wd = watchdog_interval() if cfg.health.watchdog else None
        last_wd = last_status = time.monotonic()
        self.notifier.ready(f"{cfg.vehicle.role} {cfg.vehicle.id} running")
        log.info("loop running: role=%s id=%s radar=%s camera=%s", cfg.vehicle.role, cfg.vehicle.id,
                 cfg.radar.source, cfg.camera.source)
        try:
            while not self.stop.is_set():
                rf: RadarFrame | None = self.radar_q.get(0.1)
                if rf is not None:
                    self.rates["radar"].add()
                    self._step(rf)
                elif readers[0].ended.is_set() and len(self.radar_q) == 0:
                    log.info("radar source ended; stopping")
                    break
                now = time.monotonic()
                if wd is not None and now - last_wd >= wd:
                    self.notifier.watchdog()
                    last_wd = now
                if self.identity is not None and self.identity.trust is not None:
                    self.identity.trust.maybe_reload()  # a changed file or SIGHUP: new keys now
                if now - last_status >= cfg.loop.status_interval_s:
                    self._status()
                    last_status = now
        finally:
            self.stop.set()
            self.notifier.stopping()
            for r in readers:
                r.join(timeout=5.0)
            self._status()
        return 0

    def _step(self, rf: RadarFrame) -> None:
        if RECORDED_DETECTIONS in rf.device:  # a replayed frame brings what live used
            det = rf.device[RECORDED_DETECTIONS]
            det = det if len(det.boxes) or np.isfinite(det.stamp) else None
        elif self.cfg.camera.source == "none":
            det = None
        else:
            det = self.cam_hist.closest(rf.stamp, self.cfg.loop.camera_tolerance_s,
                                        wait_s=self.cfg.loop.camera_wait_s)
        if det is None:
            boxes, feats, cam_stamp = np.zeros((0, 6), np.float32), np.zeros((0, 32), np.float32), np.nan
        else:
            boxes, feats, cam_stamp = det.boxes, det.features, det.stamp
        self.seq += 1
        frame = SensorFrame(seq=self.seq, stamp=float(rf.stamp), points=np.asarray(rf.points, np.float32),
                            boxes=np.asarray(boxes, np.float32).reshape(-1, 6),
                            features=np.asarray(feats, np.float32).reshape(-1, 32),
                            camera_stamp=float(cam_stamp), frame_number=int(rf.frame_number),
                            host_time=float(rf.host_time))
        self.rates["frames"].add()
        if self.node is None:
            if self.recorder is not None:
                self.recorder.write(logschema.POINTS,
                                    logschema.points_message(frame.points, frame.stamp, self.cfg.vehicle.id),
                                    stamp=frame.stamp)
                self.recorder.write(logschema.FRAME, logschema.frame_to_json(frame), stamp=frame.stamp)
            return
        try:
            self.node.process(frame)
        except MMatchError as exc:  # a frame the pipeline cannot handle costs that frame only
            log.warning("frame %d dropped: %s", frame.seq, exc)
            self.drops["pipeline"] += 1
        except Exception:  # a pipeline bug on odd input must not stop the vehicle service
            log.exception("frame %d dropped: pipeline failed", frame.seq)
            self.drops["pipeline_error"] += 1

    def health(self) -> dict:
        """Rates (per s since the last call), drops and counters."""
        rates = {k: round(v.rate(), 2) for k, v in self.rates.items()}
        drops = dict(self.drops)
        drops["radar_queue"] = self.radar_q.dropped
        counters: dict[str, int] = {}
        for r in self.readers:
            drops[f"{r.sensor}_errors"] = r.errors
            for k, v in r.source.counters().items():
                counters[f"{r.sensor}_{k}"] = v
        if self.transport is not None:
            for k, v in self.transport.drops.snapshot().items():
                drops[f"zenoh_{k}"] = v
        out: dict[str, Any] = {"vehicle": self.cfg.vehicle.id, "time": time.time(), "rates": rates,
                               "drops": drops, "counters": counters}
        if self.node is not None:
            out["node"] = self.node.summary()
            if self.node.verifier is not None:
                out["rx_checks"] = self.node.verifier.snapshot()
        if self.identity is not None:
            out["auth"] = self.identity.describe()
        if self.recorder is not None:
            out["recorder"] = rec = self.recorder.stats()
            for k, v in rec["dropped"].items():
                drops[f"log_{k}"] = v
        return out

    def _status(self) -> None:
        h = self.health()
        links = ""
        if self.node is not None and self.node.links:
            links = " ".join(f"{n}:{'up' if s.up else 'LOST'}" for n, s in self.node.links.items())
        if self.identity is not None and self.identity.mode == "dev":
            links = (links + " " if links else "") + "DEV KEYS"
        if h.get("recorder", {}).get("state") == "failing":
            links = (links + " " if links else "") + f"LOG FAILING: {h['recorder']['error']}"
        text = format_status(h["rates"], {k: v for k, v in h["drops"].items() if v}, links)
        log.info("status: %s", text)
        self.notifier.status(text)
        if self.transport is not None:
            try:
                data = dumps(h)
                if self.identity is not None:
                    data = seal_message(self.identity.signer, "health", data, self._health_seq.next(),
                                        time.time())
                self.transport.put(keys.health(self.cfg.vehicle.id), data)
            except Exception as exc:
                log.debug("health publish failed: %s", exc)
        if self.recorder is not None:
            self.recorder.write(logschema.HEALTH, h)
