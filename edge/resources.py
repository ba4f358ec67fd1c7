"""Files shipped with the package: example configs, radar chirp profiles, the unit file.

In the repository they are the folders `cfg/` and `systemd/`; installed, the same files
are package data of `mmatch.cfg` and `mmatch.systemd` (setup.py), so `mmatch config
--example ego` works from any folder after `pip install`.
"""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable

from mmatch.errors import ConfigError

#: name of an example -> shipped file (under cfg/)
EXAMPLES: dict[str, str] = {
    "ego": "vehicle-ego-sim.toml",
    "cav": "vehicle-cav-sim.toml",
    "field": "vehicle.toml",
    "field-ego": "vehicle-ego.toml",
}

_ROOTS = {"cfg": "mmatch.cfg", "systemd": "mmatch.systemd"}


def shipped_files() -> list[str]:
    """Every shipped data file as "cfg/..." or "systemd/...", sorted."""
    out: list[str] = []

    def walk(node: Traversable, prefix: str) -> None:
        for child in node.iterdir():
            if child.is_dir():
                if child.name != "__pycache__":
                    walk(child, f"{prefix}{child.name}/")
            elif not child.name.endswith((".py", ".pyc")):
                out.append(prefix + child.name)

    for top, package in _ROOTS.items():
        walk(resources.files(package), f"{top}/")
    return sorted(out)


def read_shipped(name: str) -> str:
    """The text of a shipped file, named as `shipped_files` lists it (a leading "cfg/" may be
    left out); ConfigError with the list when there is no such file."""
    known = shipped_files()
    key = name if name.split("/", 1)[0] in _ROOTS else f"cfg/{name}"
    if key not in known:
        raise ConfigError(f"{name}: not a shipped file; shipped: {', '.join(known)}")
    top, rest = key.split("/", 1)
    node = resources.files(_ROOTS[top])
    for part in rest.split("/"):
        node = node / part
    return node.read_text()
