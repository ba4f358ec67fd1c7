"""One exception root for the whole product, subclassed by phase."""

from __future__ import annotations


class MMatchError(Exception):
    """Root of every error MMatch raises on purpose."""


class ConfigError(MMatchError, ValueError):
    """A configuration file or value is invalid; the message names the key or line."""


class ParseError(MMatchError, ValueError):
    """Bytes or a file could not be decoded."""


class SceneFormatError(ParseError):
    """A scene or radar file breaks its format; names the file and the key."""

    def __init__(self, path: str, key: str, reason: str) -> None:
        super().__init__(f"{path}: key {key!r}: {reason}")
        self.path = path
        self.key = key
        self.reason = reason


class DecodeError(ParseError):
    """A wire frame (shared frame, TLV packet, UDP packet) is malformed."""


class DeviceError(MMatchError, OSError):
    """A sensor or network device failed."""


class DeviceTimeout(DeviceError, TimeoutError):
    """A device did not answer in time."""


class AlignmentError(MMatchError):
    """The Ego could not estimate a transform (too little shared evidence)."""
