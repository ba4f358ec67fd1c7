"""Replay backend: camera data recorded earlier, through the same interface as a live camera.

Inputs (chosen from what `path` holds):
- a folder of `mmatch-scene/1` files (`*.npz`): the `role` side's boxes, descriptors, stamp and
  camera model are replayed as recorded (no detector);
- a folder of images (`*.png`, `*.jpg`) with an optional `stamps.csv` (lines `name,stamp`;
  else a stamp every 1/`rate_hz` s from `start_stamp`): each image goes through the detector
  stage like a live frame (this is how a recorded drive is re-detected with a new model);
- any iterable of `(stamp, image)` or `Detections` given as `frames=` (for tests and for the
  vehicle log reader, which owns the MCAP format).

`realtime=True` plays at the recorded pace (sleeping between stamps); else as fast as read.
The end raises `EndOfStream`.
"""

from __future__ import annotations

import csv
import logging
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from mmatch.drivers.camera.calibration import Calibration
from mmatch.drivers.camera.errors import CameraUnavailable, EndOfStream
from mmatch.drivers.camera.pipeline import DetectionStage
from mmatch.drivers.camera.sources.base import CameraSource
from mmatch.types import CameraModel, Detections

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


def _scene_items(files: list[Path], role: str) -> Iterator[Detections | CameraModel]:
    from mmatch.scene_io import load_scene

    for f in files:
        try:
            scene = load_scene(f)
        except Exception as exc:  # a rejected file is logged and skipped, the replay goes on
            log.warning("replay: skipping %s: %s", f, exc)
            continue
        view = scene.ego if role == "ego" else scene.cav
        yield view.camera
        yield Detections(
            boxes=view.boxes.astype(np.float32),
            features=view.features.astype(np.float32),
            stamp=float(view.stamp),
        )


def _read_stamps(folder: Path) -> dict[str, float]:
    p = folder / "stamps.csv"
    if not p.is_file():
        return {}
    out: dict[str, float] = {}
    with open(p, newline="") as f:
        for row in csv.reader(f):
            if len(row) >= 2 and not row[0].startswith("#"):
                try:
                    out[row[0].strip()] = float(row[1])
                except ValueError:
                    continue
    return out


class ReplayCamera(CameraSource):
    """Replays scene files, image folders or an iterable of frames."""

    name = "replay"
    lossless = True

    def __init__(
        self,
        path: str | Path | None = None,
        *,
        stage: DetectionStage | None = None,
        calibration: Calibration | None = None,
        frames: Iterable | None = None,
        role: str = "ego",
        realtime: bool = False,
        rate_hz: float = 10.0,
        start_stamp: float = 0.0,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if path is None and frames is None:
            raise ValueError("ReplayCamera needs a path or frames")
        self.path = None if path is None else Path(path)
        self.stage = stage
        self._calibration = calibration or (stage.calibration if stage else None)
        self._frames = frames
        self.role = role
        self.realtime = realtime
        self.rate_hz = rate_hz
        self.start_stamp = start_stamp
        self._sleep = sleep
        self._it: Iterator | None = None
        self._camera: CameraModel | None = None
        self._last: tuple[float, float] | None = None  # (stamp, wall time) of the previous frame
        self._count = 0
        self._skipped = 0

    # -- opening ---------------------------------------------------------------------------
    def open(self) -> None:
        if self._it is not None:
            return
        if self._frames is not None:
            self._it = iter(self._frames)
            return
        if not self.path.exists():
            raise CameraUnavailable(f"replay {self.path}: no such file or folder")
        if self.path.is_file():
            raise CameraUnavailable(
                f"replay {self.path}: expected a folder of scene files or images "
                "(video files play through the opencv backend)"
            )
        scenes = sorted(self.path.glob("*.npz"))
        images = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if scenes:
            self._it = _scene_items(scenes, self.role)
        elif images:
            if self.stage is None:
                raise CameraUnavailable(
                    f"replay {self.path}: image folder needs a detector stage (model + calibration)"
                )
            self._it = self._image_items(images)
        else:
            raise CameraUnavailable(f"replay {self.path}: no *.npz scene files and no images")

    def _image_items(self, images: list[Path]) -> Iterator[tuple[float, np.ndarray | None]]:
        import cv2

        stamps = _read_stamps(self.path)
        for i, p in enumerate(images):
            stamp = stamps.get(p.name, self.start_stamp + i / self.rate_hz)
            yield stamp, cv2.imread(str(p), cv2.IMREAD_COLOR)

    # -- interface -------------------------------------------------------------------------
    @property
    def camera(self) -> CameraModel:
        if self._camera is None and self._calibration is not None:
            self._camera = self._calibration.camera_model()
        if self._camera is None:
            self.open()
            self._peek_camera()
        if self._camera is None:
            raise CameraUnavailable(f"replay {self.path}: no camera model (give a calibration)")
        return self._camera

    def _peek_camera(self) -> None:
        item = next(self._it, None)
        if isinstance(item, CameraModel):
            self._camera = item
        elif item is not None:
            import itertools

            self._it = itertools.chain([item], self._it)

    def read(self, timeout: float) -> Detections | None:
        if self._it is None:
            self.open()
        while True:
            item = next(self._it, None)
            if item is None:
                raise EndOfStream(
                    f"replay {self.path or '<frames>'}: end after {self._count} frames"
                )
            if isinstance(item, CameraModel):
                self._camera = item
                continue
            break
        if isinstance(item, Detections):
            det, stamp = item, item.stamp
        else:
            stamp, image = item
            if self.stage is None:
                raise CameraUnavailable("replay: image frames need a detector stage")
            det = self.stage.process(image, float(stamp))
        self._pace(float(stamp))
        self._count += 1
        if det is None:
            self._skipped += 1
        return det

    def _pace(self, stamp: float) -> None:
        now = time.monotonic()
        if self.realtime and self._last is not None and np.isfinite(stamp):
            wait = (stamp - self._last[0]) - (now - self._last[1])
            if 0 < wait < 10:
                self._sleep(wait)
                now = time.monotonic()
        self._last = (stamp, now)

    def counters(self) -> dict[str, int]:
        out = {"frames": self._count, "skipped": self._skipped}
        if self.stage is not None:
            out.update({f"stage_{k}": v for k, v in self.stage.counters.as_dict().items()})
        return out

    def close(self) -> None:
        self._it = None
