"""The methods a report compares: each a matcher and an aligner by registry name.

Groups: "ours" (MMatch and its aligner with the true pairs), "yardstick" (true pairs +
centroid ICP), "ablation" (the paper's alignment as written and its ICP ablation, on
MMatch's pairs) and "peer" (general point-cloud registration, `baselines` extra, no
pairs). A method whose matcher or aligner is not registered is left out of the default
list (a learned matcher appears once it is on main); one whose library is missing is
skipped by the run with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass

from mmatch.ego.registry import DEFAULT_MATCHER
from mmatch.errors import ConfigError


@dataclass(frozen=True)
class Method:
    """key: short name (file names, --methods); label: as printed; group: see the module doc."""

    key: str
    label: str
    matcher: str
    aligner: str
    group: str = "ours"

    @property
    def spec(self) -> str:
        return f"{self.matcher}+{self.aligner}"


METHODS: tuple[Method, ...] = (
    Method("mmatch", "MMatch", DEFAULT_MATCHER, "constrained", "ours"),
    Method("rmnet", "MMatch, RM-net matcher", "rmnet", "constrained", "ours"),
    Method("true-pairs", "MMatch aligner, true pairs", "oracle", "constrained", "ours"),
    Method("yardstick", "true pairs + centroid ICP", "oracle", "centroid-icp", "yardstick"),
    Method("paper", "paper's alignment as written", DEFAULT_MATCHER, "paper", "ablation"),
    Method("icp-all", "ICP-All", DEFAULT_MATCHER, "icp-all", "ablation"),
    Method("icp-bg", "ICP-BG", DEFAULT_MATCHER, "icp-bg", "ablation"),
    Method("icp-veh", "ICP-Veh", DEFAULT_MATCHER, "icp-veh", "ablation"),
    Method("icp-pair", "ICP-Pair", DEFAULT_MATCHER, "icp-pair", "ablation"),
    Method("o3d-icp", "Open3D ICP (point-to-point)", "none", "o3d-icp", "peer"),
    Method("o3d-fgr", "Open3D FGR on FPFH", "none", "o3d-fgr", "peer"),
    Method("o3d-ransac", "Open3D RANSAC on FPFH", "none", "o3d-ransac", "peer"),
    Method("gicp", "small_gicp GICP", "none", "gicp", "peer"),
)
REFERENCE = "mmatch"
# drawn in the breakdown figures (all methods are in the tables and the CDFs)
HEADLINE = ("mmatch", "rmnet", "true-pairs", "yardstick", "paper", "o3d-ransac", "gicp")


def _registered(m: Method) -> bool:
    from mmatch.ego.registry import ALIGNERS, MATCHERS
    return m.matcher in MATCHERS and m.aligner in ALIGNERS


def default_methods() -> list[Method]:
    """Every method of METHODS whose matcher and aligner are registered."""
    return [m for m in METHODS if _registered(m)]


def resolve(names: list[str]) -> list[Method]:
    """Methods from keys of METHODS or MATCHER+ALIGNER specs (ConfigError naming a bad one)."""
    from mmatch.ego.registry import ALIGNERS, MATCHERS
    by_key = {m.key: m for m in METHODS}
    out: list[Method] = []
    for name in names:
        name = name.strip()
        if not name:
            continue
        if name in by_key:
            m = by_key[name]
        elif "+" in name:
            matcher, aligner = name.split("+", 1)
            m = Method(name, name, matcher, aligner, "custom")
        else:
            raise ConfigError(f"unknown method {name!r}; choose from {', '.join(by_key)} "
                              "or give MATCHER+ALIGNER")
        if m.matcher not in MATCHERS:
            raise ConfigError(f"method {name!r}: unknown matcher {m.matcher!r}; "
                              f"choose one of {', '.join(sorted(MATCHERS))}")
        if m.aligner not in ALIGNERS:
            raise ConfigError(f"method {name!r}: unknown aligner {m.aligner!r}; "
                              f"choose one of {', '.join(sorted(ALIGNERS))}")
        if m.key in {x.key for x in out}:
            raise ConfigError(f"method {name!r} given twice")
        out.append(m)
    if not out:
        raise ConfigError("no methods given")
    return out


def unavailable(m: Method) -> str | None:
    """Why the method cannot run on this machine (a missing optional library), or None."""
    from mmatch.ego.align.baselines import missing_extra
    return missing_extra(m.aligner)
