"""Matchers and aligners by name; the implementations are imported only when asked for."""

from __future__ import annotations

import importlib

from mmatch.errors import ConfigError

MATCHERS: dict[str, str] = {
    "oracle": "mmatch.ego.match.oracle:OracleMatcher",
    "consensus": "mmatch.ego.match.consensus:ConsensusMatcher",
}
ALIGNERS: dict[str, str] = {
    "centroid-icp": "mmatch.ego.align.centroid_icp:CentroidICPAligner",
    "anchored-icp": "mmatch.ego.align.anchored:AnchoredICPAligner",
    "constrained": "mmatch.ego.align.constrained:ConstrainedAligner",
}
DEFAULT_MATCHER = "consensus"
DEFAULT_ALIGNER = "constrained"


def _load(table: dict[str, str], kind: str, name: str):
    if name not in table:
        raise ConfigError(f"unknown {kind} {name!r}; choose one of {', '.join(sorted(table))}")
    module, cls = table[name].split(":")
    return getattr(importlib.import_module(module), cls)()


def get_matcher(name: str):
    """A matcher instance: callable (own, other, ctx) -> MatchResult."""
    return _load(MATCHERS, "matcher", name)


def get_aligner(name: str):
    """An aligner instance: callable (own, other, match) -> AlignResult."""
    return _load(ALIGNERS, "aligner", name)
