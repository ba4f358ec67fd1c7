"""Zenoh key expressions of DESIGN.md, built in one place.

`mmatch/v1/<vehicle>/shared` (shared frames), `mmatch/v1/<vehicle>/fused` (Ego result),
`mmatch/v1/<vehicle>/health`.
"""

from __future__ import annotations

from mmatch.errors import ConfigError

PREFIX = "mmatch/v1"
KINDS = ("shared", "fused", "health")


def _check_vehicle(vehicle: str) -> str:
    if not vehicle or any(c in vehicle for c in "/*$?# "):
        raise ConfigError(f"vehicle id {vehicle!r} cannot be a key expression segment")
    return vehicle


def shared(vehicle: str) -> str:
    """Key of the shared frames `vehicle` publishes."""
    return f"{PREFIX}/{_check_vehicle(vehicle)}/shared"


def fused(vehicle: str) -> str:
    """Key of the fused results the Ego `vehicle` publishes."""
    return f"{PREFIX}/{_check_vehicle(vehicle)}/fused"


def health(vehicle: str) -> str:
    """Key of `vehicle`'s health summaries."""
    return f"{PREFIX}/{_check_vehicle(vehicle)}/health"


def all_of(kind: str) -> str:
    """Key expression matching `kind` from every vehicle (e.g. every shared frame)."""
    if kind not in KINDS:
        raise ValueError(f"unknown key kind {kind!r}")
    return f"{PREFIX}/*/{kind}"


def parse(key: str) -> tuple[str, str] | None:
    """(vehicle, kind) of a concrete key, or None when it is not one of ours."""
    parts = str(key).split("/")
    if len(parts) != 4 or "/".join(parts[:2]) != PREFIX or parts[3] not in KINDS or not parts[2]:
        return None
    return parts[2], parts[3]
