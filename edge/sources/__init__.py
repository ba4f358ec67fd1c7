"""Sensor sources: one small interface per device kind, backends chosen by name.

Radar backends: uart, dca1000, replay, sim, scene. Camera backends: opencv, oak, replay, sim, scene.
`open_radar(cfg)` / `open_camera(cfg)` look the backend up by the name in the config and
import it only then (heavy libraries stay out of `mmatch --help`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from mmatch.errors import ConfigError

if TYPE_CHECKING:
    from mmatch.edge.config import VehicleConfig
    from mmatch.edge.sources.base import CameraSource, RadarSource

RADAR_BACKENDS: dict[str, str] = {
    "uart": "mmatch.edge.sources.uart:UartRadar",
    "dca1000": "mmatch.edge.sources.dca1000:Dca1000Radar",
    "replay": "mmatch.edge.sources.replay:ReplayRadar",
    "sim": "mmatch.edge.sources.sim:SimRadar",
    "scene": "mmatch.edge.sources.scene:SceneRadar",
}
CAMERA_BACKENDS: dict[str, str] = {
    "opencv": "mmatch.edge.sources.camera:OpenCvCamera",
    "oak": "mmatch.edge.sources.camera:OakCamera",
    "replay": "mmatch.edge.sources.replay:ReplayCamera",
    "sim": "mmatch.edge.sources.sim:SimCamera",
    "scene": "mmatch.edge.sources.scene:SceneCamera",
    "none": "mmatch.edge.sources.base:NoCamera",
}


def _lookup(table: dict[str, str], name: str, kind: str) -> type:
    try:
        module_name, cls = table[name].split(":")
    except KeyError:
        raise ConfigError(f"{kind}.source: unknown backend {name!r} (known: {', '.join(table)})") from None
    return getattr(importlib.import_module(module_name), cls)


def open_radar(cfg: VehicleConfig, **kw) -> RadarSource:
    """The radar backend named by `cfg.radar.source`, constructed (not yet opened)."""
    return _lookup(RADAR_BACKENDS, cfg.radar.source, "radar")(cfg, **kw)


def open_camera(cfg: VehicleConfig, **kw) -> CameraSource:
    """The camera backend named by `cfg.camera.source`, constructed (not yet opened)."""
    return _lookup(CAMERA_BACKENDS, cfg.camera.source, "camera")(cfg, **kw)
