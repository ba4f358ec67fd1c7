"""Matchers and aligners by name; the implementations are imported only when asked for."""

from __future__ import annotations

import importlib

from mmatch.errors import ConfigError

MATCHERS: dict[str, str] = {
    "oracle": "mmatch.ego.match.oracle:OracleMatcher",
    "consensus": "mmatch.ego.match.consensus:ConsensusMatcher",
    "consensus-rmnet": "mmatch.ego.match.consensus_rmnet:ConsensusRMNetMatcher",
    "none": "mmatch.ego.match.none:NoMatcher",
    "rmnet": "mmatch.ego.match.rmnet:RMNetMatcher",
    "rmnet-only": "mmatch.ego.match.rmnet:RMNetOnlyMatcher",
    "geometry": "mmatch.ego.match.rmnet:GeometryMatcher",
    "descriptor": "mmatch.ego.match.rmnet:DescriptorMatcher",
}
ALIGNERS: dict[str, str] = {
    "centroid-icp": "mmatch.ego.align.centroid_icp:CentroidICPAligner",
    "anchored-icp": "mmatch.ego.align.anchored:AnchoredICPAligner",
    "constrained": "mmatch.ego.align.constrained:ConstrainedAligner",
    "paper": "mmatch.ego.align.paper:PaperAligner",
    "icp-all": "mmatch.ego.align.icp_ablation:ICPAllAligner",
    "icp-bg": "mmatch.ego.align.icp_ablation:ICPBackgroundAligner",
    "icp-veh": "mmatch.ego.align.icp_ablation:ICPVehicleAligner",
    "icp-pair": "mmatch.ego.align.icp_ablation:ICPPairAligner",
    # point-cloud peers, `baselines` extra (run them with the `none` matcher)
    "o3d-icp": "mmatch.ego.align.baselines:O3DICPAligner",
    "o3d-fgr": "mmatch.ego.align.baselines:O3DFGRAligner",
    "o3d-ransac": "mmatch.ego.align.baselines:O3DRansacAligner",
    "gicp": "mmatch.ego.align.baselines:GICPAligner",
}
DEFAULT_MATCHER = "consensus-rmnet"
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
    """An aligner instance: callable (own, other, match) -> AlignResult. It may also offer
    `polish(own, other, pairs, T, descriptor_scale, quick) -> (T, information or None)`, which the
    Fuser applies to the transform it chose (`constrained`: with the vehicles' sightings of each
    other; quick: a tracking frame)."""
    return _load(ALIGNERS, "aligner", name)
