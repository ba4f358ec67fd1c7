"""The `none` matcher: no pairs and no transform, for aligners that register the point clouds alone."""

from __future__ import annotations

from mmatch.ego.base import MatchContext, MatchResult
from mmatch.shared import SharedFrame


class NoMatcher:
    name = "none"

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        """Always empty: the point-cloud peers (ego/align/baselines.py) find no co-visible vehicles."""
        return MatchResult()
