"""The `oracle` matcher: the scene file's ground-truth pairs (the yardstick for every matcher)."""

from __future__ import annotations

import numpy as np

from mmatch.ego.base import MatchContext, MatchResult
from mmatch.shared import SharedFrame


class OracleMatcher:
    name = "oracle"

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        """Pairs of vehicles whose source boxes are a ground-truth pair; needs ctx.gt_box_pairs."""
        gt = ctx.gt_box_pairs if ctx.gt_box_pairs is not None else np.zeros((0, 2), np.int32)
        own_of_box = {int(b): v for v, b in enumerate(own.vehicle_box_index)}
        other_of_box = {int(b): v for v, b in enumerate(other.vehicle_box_index)}
        pairs = [(own_of_box[a], other_of_box[b]) for a, b in gt
                 if int(a) in own_of_box and int(b) in other_of_box]
        arr = np.array(pairs, np.int32).reshape(-1, 2)
        return MatchResult(pairs=arr, scores=np.ones(len(arr)))
