"""Scene files as sensors: one drive of `mmatch-scene/1` files played through `mmatch run`.

`SceneRadar` reads `scene.path` and plays one drive (`scene.sequence`; docs/formats.md
"Sequences") from one side of the files (`scene.view`): each frame's radar points at its
capture stamp, carrying the camera detections of the same file (as a replayed frame carries
the detections the live loop used, `RECORDED_DETECTIONS`), so radar and camera pair exactly as
the files pair them. `SceneCamera` gives that side's camera model.

The files' stamps are kept as they are (a result can be compared bit for bit with `mmatch eval
--sequences` on the same files): the source keeps the drive's own clock, `clock()` = the
drive's time now = first Ego stamp + (time.time() - `scene.start`), and delivers a frame when
that clock reaches its stamp minus `scene.lead_s`. The vehicle loop gives this clock to the
Node and the receiver's stamp checks, so waiting for a CAV frame, the link state and the
acceptance window all run on it. Two vehicles of one drive (each its own process) need the same
`scene.start`; a CAV that leads its Ego (`scene.lead_s`) has its shared frames there first. The
source is lossless: the loop blocks rather than drops.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from mmatch.edge.config import VehicleConfig
from mmatch.edge.sources.base import CameraSource, EndOfStream, RadarSource
from mmatch.edge.sources.replay import RECORDED_DETECTIONS
from mmatch.errors import ConfigError, SceneFormatError
from mmatch.types import CameraModel, Detections, RadarFrame

log = logging.getLogger(__name__)

STARTUP_S = 2.0          # scene.start = 0: the first Ego frame is due this long after the source is made


def scene_view(cfg: VehicleConfig) -> str:
    """"ego" or "cav": the side of the files this vehicle plays."""
    if cfg.scene.view != "auto":
        return cfg.scene.view
    return "cav" if cfg.vehicle.role == "cav" else "ego"


def drive_files(cfg: VehicleConfig) -> list[str]:
    """The files of the drive `scene.sequence` (the first one when empty) in frame order;
    ConfigError naming scene.path / scene.sequence when there is nothing to play."""
    from mmatch.sequence_eval import group_sequences

    folder = Path(cfg.scene.path)
    if not folder.is_dir():
        raise ConfigError(f"scene.path: {folder} is not a folder of scene files")
    groups, rejected = group_sequences(sorted(str(p) for p in folder.glob("*.npz")))
    for r in rejected:
        log.warning("scene source: %s", r["rejected"])
    if not groups:
        raise ConfigError(f"scene.path: {folder} holds no drive (files with meta.sequence and meta.frame)")
    name = cfg.scene.sequence or sorted(groups)[0]
    if name not in groups:
        raise ConfigError(f"scene.sequence: {name!r} is not in {folder} (there: {', '.join(sorted(groups))})")
    return [f for _, f in groups[name]]


class SceneRadar(RadarSource):
    """The radar of one side of a drive's scene files, on the drive's clock."""

    lossless = True

    def __init__(self, cfg: VehicleConfig, **kw: Any) -> None:
        from mmatch.scene_io import load_scene

        self.cfg = cfg
        self.view = scene_view(cfg)
        self.files = drive_files(cfg)
        try:
            first = load_scene(self.files[0])
        except SceneFormatError as exc:
            raise ConfigError(f"scene.path: {exc}") from exc
        side = getattr(first, self.view)
        self.camera_model: CameraModel = side.camera
        self.radar_height = float(side.radar_height)
        self.t0 = float(first.ego.stamp)                     # the drive's clock starts at the first Ego frame
        start = cfg.scene.start if cfg.scene.start > 0 else time.time() + STARTUP_S
        self._offset = start - self.t0                       # wall time - drive time
        self._next = 0
        self._due: Any = None                                # files[_next] once read, until delivered
        self.frames = 0
        self.rejected = 0
        self._closed = threading.Event()
        log.info("scene source: %d frames of %s as the %s, first due at %.3f", len(self.files),
                 getattr(first, "meta", {}).get("sequence", "?"), self.view, start)

    def clock(self) -> float:
        """The drive's time now, s (the files' capture stamps are on it)."""
        return time.time() - self._offset

    def read(self, timeout: float) -> RadarFrame | None:
        from mmatch.scene_io import load_scene

        while self._next < len(self.files):
            if self._due is None:
                try:
                    self._due = load_scene(self.files[self._next])
                except SceneFormatError as exc:
                    log.warning("scene source: %s; skipped", exc)
                    self.rejected += 1
                    self._next += 1
                    continue
            scene = self._due
            side = getattr(scene, self.view)
            wait = float(side.stamp) - self.cfg.scene.lead_s - self.clock()
            if wait > timeout:
                self._closed.wait(timeout)
                return None
            if wait > 0:
                self._closed.wait(wait)
            self._next += 1
            self._due = None
            self.frames += 1
            det = Detections(boxes=np.asarray(side.boxes, np.float32), features=np.asarray(side.features, np.float32),
                             stamp=float(side.stamp))
            return RadarFrame(points=np.asarray(side.points, np.float32), stamp=float(side.stamp),
                              frame_number=int(scene.meta.get("frame", self._next - 1)), host_time=time.time(),
                              device={RECORDED_DETECTIONS: det})
        raise EndOfStream(f"scene {self.cfg.scene.path}: end of the drive")

    def counters(self) -> dict[str, int]:
        return {"frames": self.frames, "rejected_files": self.rejected}

    def close(self) -> None:
        pass  # the position stays, so a reopen continues where it was


class SceneCamera(CameraSource):
    """The camera model of the played side; its detections travel with the radar frames."""

    lossless = True

    def __init__(self, cfg: VehicleConfig, *, radar: RadarSource | None = None, **kw: Any) -> None:
        if not isinstance(radar, SceneRadar):
            raise ConfigError("camera.source: \"scene\" needs radar.source = \"scene\"")
        self._camera = radar.camera_model
        self._closed = threading.Event()

    @property
    def camera(self) -> CameraModel:
        return self._camera

    def read(self, timeout: float) -> Detections | None:
        self._closed.wait(timeout)
        return None

    def close(self) -> None:
        self._closed.set()
