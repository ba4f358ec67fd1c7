"""Camera-driver exceptions (subclasses of mmatch.errors, one per phase)."""

from __future__ import annotations

from mmatch.errors import ConfigError, DeviceError, MMatchError


class ModelError(ConfigError):
    """A detector model is missing or incompatible; the message names the file and what was
    expected."""

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = str(path)
        self.reason = reason


class CalibrationError(ConfigError):
    """A calibration file or value is invalid; the message names the file and the key."""

    def __init__(self, path: str, key: str, reason: str) -> None:
        super().__init__(f"{path}: key {key!r}: {reason}")
        self.path = str(path)
        self.key = key
        self.reason = reason


class CameraUnavailable(DeviceError):
    """A camera could not be opened or stopped delivering frames."""


class EndOfStream(MMatchError):
    """A finite camera source (replay folder, video file) has no more frames."""
