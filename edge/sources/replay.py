"""Replay sources: a field log or a raw UART capture as the radar (and camera) of `mmatch run`.

`ReplayRadar` reads `radar.path`: an MCAP log gives its recorded point clouds (and hands
the recorded detections to a `ReplayCamera` made with `radar=`), a raw UART capture goes
through the TI streaming reader. Pace per `radar.pace` / `radar.speed`. These sources are
lossless: the loop blocks rather than drops, so a replay sees every frame.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from typing import Any

from edge import logreader
from edge.config import VehicleConfig
from edge.logschema import camera_from_meta
from edge.replay import Pacer, capture_frames, log_events, log_metadata
from edge.sources.base import CameraSource, EndOfStream, RadarSource, default_camera
from edge.transport import KeepNewest
from mmatch.errors import MMatchError
from mmatch.types import CameraModel, Detections, RadarFrame

log = logging.getLogger(__name__)


class ReplayRadar(RadarSource):
    lossless = True

    def __init__(self, cfg: VehicleConfig, **kw: Any) -> None:
        self.cfg = cfg
        self.path = cfg.radar.path
        self.is_log = logreader.is_mcap(self.path) or os.path.isdir(self.path)
        self.report = logreader.LogReport()
        self.capture_stats: dict = {}
        self._it: Iterator[RadarFrame] | None = None
        self.camera_feed: KeepNewest[Detections] | None = None
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
            if self.camera_feed is not None and len(f.boxes):
                self.camera_feed.put(Detections(boxes=f.boxes, features=f.features,
                                                stamp=f.camera_stamp if f.camera_stamp == f.camera_stamp else f.stamp))
            yield RadarFrame(points=f.points, stamp=f.stamp, frame_number=f.frame_number, host_time=f.host_time)

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
    """The detections recorded in a log, delivered with the replayed radar frames."""

    lossless = True

    def __init__(self, cfg: VehicleConfig, *, radar: RadarSource | None = None, **kw: Any) -> None:
        self._feed: KeepNewest[Detections] = KeepNewest(64)
        if isinstance(radar, ReplayRadar):
            radar.camera_feed = self._feed
        else:
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

    @property
    def camera(self) -> CameraModel:
        return self._camera

    def read(self, timeout: float) -> Detections | None:
        return self._feed.get(timeout)

    def close(self) -> None:
        self._feed.close()
