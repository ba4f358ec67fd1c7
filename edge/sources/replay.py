"""Replay sources: a field log or a raw UART capture as the radar (and camera) of `mmatch run`.

`ReplayRadar` reads `radar.path`: an MCAP log gives its recorded point clouds and detections, a raw UART capture goes
through the TI streaming reader. A replayed frame carries the detections the live loop
used with it. Pace per `radar.pace` / `radar.speed`. These sources are
lossless: the loop blocks rather than drops, so a replay sees every frame.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Iterator
from typing import Any

from mmatch.edge import logreader
from mmatch.edge.config import VehicleConfig
from mmatch.edge.logschema import camera_from_meta
from mmatch.edge.replay import Pacer, capture_frames, log_events, log_metadata
from mmatch.edge.sources.base import CameraSource, EndOfStream, RadarSource, default_camera
from mmatch.errors import MMatchError
from mmatch.types import CameraModel, Detections, RadarFrame

log = logging.getLogger(__name__)

#: RadarFrame.device key of the camera detections recorded with a replayed frame
RECORDED_DETECTIONS = "recorded_detections"


class ReplayRadar(RadarSource):
    lossless = True

    def __init__(self, cfg: VehicleConfig, **kw: Any) -> None:
        self.cfg = cfg
        self.path = cfg.radar.path
        self.is_log = logreader.is_mcap(self.path) or os.path.isdir(self.path)
        self.report = logreader.LogReport()
        self.capture_stats: dict = {}
        self._it: Iterator[RadarFrame] | None = None
        self.frames = 0
        self.radar_height = cfg.radar.height_m
        if self.is_log:
            meta = log_metadata(self.path).get("camera")
            if meta:
                self.radar_height = camera_from_meta(meta)[1]

    def open(self) -> None:
        if self._it is None:
            self._it = self._log_frames() if self.is_log else self._capture_frames()

    def _log_frames(self) -> Iterator[RadarFrame]:
        pacer = Pacer(self.cfg.radar.pace == "fast", self.cfg.radar.speed)
        for ev in log_events(self.path, self.report):
            if ev.kind != "frame":
                continue
            pacer.wait(ev.log_time_ns)
            f = ev.frame
            # the detections the live loop used with this frame (none is an answer too), so a
            # replay pairs radar and camera exactly as live did
            det = Detections(boxes=f.boxes, features=f.features, stamp=f.camera_stamp)
            yield RadarFrame(points=f.points, stamp=f.stamp, frame_number=f.frame_number, host_time=f.host_time,
                             device={RECORDED_DETECTIONS: det})

    def _capture_frames(self) -> Iterator[RadarFrame]:
        baud = None if self.cfg.radar.pace == "fast" else int(self.cfg.radar.baudrate * self.cfg.radar.speed)
        yield from capture_frames(self.path, pace_baud=baud, stats_out=self.capture_stats)

    def read(self, timeout: float) -> RadarFrame | None:
        if self._it is None:
            self.open()
        try:
            frame = next(self._it)
        except StopIteration:
            raise EndOfStream(f"replay {self.path}: end") from None
        self.frames += 1
        return frame

    def counters(self) -> dict[str, int]:
        return {"frames": self.frames, "truncated_files": len(self.report.truncated),
                "bytes_skipped": int(self.capture_stats.get("bytes_skipped", 0))}

    def close(self) -> None:
        pass  # the iterator stays, so a reopen continues where it was


class ReplayCamera(CameraSource):
    """The camera of a replayed log: its camera model; the recorded detections travel with
    the replayed radar frames (`RECORDED_DETECTIONS`), so `read` has nothing to give."""

    lossless = True

    def __init__(self, cfg: VehicleConfig, *, radar: RadarSource | None = None, **kw: Any) -> None:
        if not isinstance(radar, ReplayRadar):
            log.warning("camera replay without a replay radar: no detections")
        self._camera = default_camera()
        try:
            meta = log_metadata(cfg.camera.path).get("camera")
            if meta:
                self._camera = camera_from_meta(meta)[0]
            else:
                log.warning("camera replay: %s holds no camera model; using a default", cfg.camera.path)
        except MMatchError as exc:
            log.warning("camera replay: %s; using a default camera model", exc)
        self._closed = threading.Event()

    def read(self, timeout: float) -> Detections | None:
        self._closed.wait(timeout)
        return None

    def close(self) -> None:
        self._closed.set()

    @property
    def camera(self) -> CameraModel:
        return self._camera
