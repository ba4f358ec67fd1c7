"""Camera backends behind one interface, chosen by name: opencv, oak, replay, sim.

`open_camera(source, ...)` builds (does not open) the backend; heavy imports happen there.
Detector settings for an ONNX model come from `detector=` (a dict of DetectorConfig keys) or,
when not given, from a sidecar TOML next to the model (`yolov8n.onnx` -> `yolov8n.toml`,
keys of DetectorConfig at top level); OAK settings likewise from `oak=` or the sidecar
(`model.tar.xz` -> `model.toml`). Unknown keys are refused by name.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from mmatch.drivers.camera.errors import ModelError
from mmatch.drivers.camera.sources.base import CameraSource
from mmatch.errors import ConfigError

BACKENDS = ("opencv", "oak", "replay", "sim")


def _sidecar(model: str) -> dict:
    p = Path(model)
    name = p.name
    for suffix in (".tar.xz", ".tar.gz", ".tgz", ".tar", ".onnx", ".blob"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    side = p.with_name(name + ".toml")
    if not side.is_file():
        return {}
    try:
        with open(side, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(str(side), f"detector settings are not valid TOML: {exc}") from exc


def open_camera(
    source: str,
    *,
    device: str = "0",
    calibration: str = "",
    model: str = "",
    path: str = "",
    threads: int = 1,
    detector: dict | None = None,
    oak: dict | None = None,
    radar_height: float | None = None,
    seed: int = 1,
    mode: str = "mixed",
    role: str = "ego",
    rate_hz: float = 20.0,
    realtime: bool = False,
) -> CameraSource:
    """The camera backend `source`, constructed and checked (model, calibration), not yet opened.

    Fails at once with ModelError / CalibrationError / ConfigError naming the file or key.
    """
    if source == "sim":
        from mmatch.drivers.camera.sources.sim import SimCamera

        return SimCamera(seed=seed, mode=mode, role=role, rate_hz=rate_hz)
    if source not in BACKENDS:
        raise ConfigError(
            f"camera.source: unknown backend {source!r} (known: {', '.join(BACKENDS)})"
        )
    from mmatch.drivers.camera.calibration import load_calibration

    calib = load_calibration(calibration) if calibration else None
    if source == "oak":
        from mmatch.drivers.camera.sources.oak import OakCamera, OakConfig

        if calib is None:
            raise ConfigError("camera.calibration: required for the oak backend")
        settings = dict(oak if oak is not None else _sidecar(model))
        settings.setdefault("model", model)
        try:
            cfg = OakConfig(**settings)
        except TypeError as exc:
            raise ConfigError(f"oak: {exc}") from exc
        return OakCamera(cfg, calib, radar_height=radar_height)
    stage = None
    if model:
        from mmatch.drivers.camera.detector import DetectorConfig, OnnxDetector
        from mmatch.drivers.camera.pipeline import DetectionStage

        if calib is None:
            raise ConfigError(
                f"camera.calibration: required with a detector model for the {source} backend"
            )
        settings = dict(detector if detector is not None else _sidecar(model))
        settings.setdefault("model", model)
        settings.setdefault("threads", threads)
        det = OnnxDetector(DetectorConfig.from_dict(settings))
        stage = DetectionStage(det.detect, calib, radar_height=radar_height)
    if source == "opencv":
        from mmatch.drivers.camera.sources.opencv import OpenCvCamera

        if stage is None:
            raise ConfigError(
                "camera.model: required for the opencv backend (an ONNX vehicle detector)"
            )
        return OpenCvCamera(device, stage)
    from mmatch.drivers.camera.sources.replay import ReplayCamera

    if not path:
        raise ConfigError("camera.path: required for the replay backend")
    return ReplayCamera(
        path, stage=stage, calibration=calib, role=role, realtime=realtime, rate_hz=rate_hz
    )


__all__ = ["BACKENDS", "CameraSource", "open_camera"]
