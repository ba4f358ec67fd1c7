"""The `consensus-rmnet` matcher (default): the consensus search fixes the transform, RM-net picks the pairs.

The two matchers are good at different things. `consensus` (no learning) finds the transform
at least as often as `rmnet` (success 0.700 against 0.696 on 1000 wide hard scenes, seeds
5-9), and its candidates carry the evidence the confidence model was fit on. RM-net knows
better which vehicles both views share: under a given transform its assignment (Mahalanobis
distance plus the network's score, `RMNetMatcher.pairs_under`) rejects look-alikes that
happen to lie near each other. So this matcher searches, scores and refines exactly as
`consensus` does (the transform, the hypotheses the arbiter weighs and the confidence are
the same), and the fused pairs under the published transform (`pairs_from_transform`,
fusion.py) are RM-net's.

Measured with the confidence gate on (fused pairs, `mmatch eval`): pair F1 0.835 -> 0.886 on
1000 wide hard scenes of seeds 5-9 (precision 0.823 -> 0.916, recall 0.848 -> 0.859), 0.884
-> 0.914 on 600 wide easy scenes of seeds 11-13; success, coverage and gross rates unchanged
by construction. Cost: the graph and one RM-net inference per frame pair (about 0.5-1 ms in
typical traffic).

Dense traffic: the consensus search draws its hypotheses from every two look-alike pairs, so
its cost grows with the fourth power of the vehicles in view until its coarse budget caps it
(86 ms median at 37.5 vehicles a view against 20 ms for `rmnet`, README). Above
`dense_pairs` own x other vehicles (default 15 x 15; no simulated scene of ours comes near:
at most 12 x 10 in 30-40 vehicle traffic, whose cameras see 7 a view median) the frame is
matched by `rmnet` whole, whose search grows with the square.

The ONNX model loads when the matcher is built: a missing or corrupt file fails at start,
naming the file (rmnet_runtime.py).
"""

from __future__ import annotations

import numpy as np

from mmatch.ego.base import MatchContext, MatchResult
from mmatch.ego.match.consensus import ConsensusConfig, ConsensusMatcher
from mmatch.ego.match.rmnet import RMNetConfig, RMNetMatcher
from mmatch.shared import SharedFrame


class ConsensusRMNetMatcher(ConsensusMatcher):
    name = "consensus-rmnet"
    pairs_from_transform = True     # the fused pairs are RM-net's under the published transform
    pairs_by_rmnet = True           # pairs_under is its RM-net's assignment (what the confidence evidence makes)

    def __init__(self, config: ConsensusConfig = ConsensusConfig(), rmnet: RMNetConfig = RMNetConfig(),
                 dense_pairs: int = 225) -> None:
        super().__init__(config)
        self.rmnet = RMNetMatcher(rmnet)
        self.dense_pairs = dense_pairs

    def __call__(self, own: SharedFrame, other: SharedFrame, ctx: MatchContext) -> MatchResult:
        """The consensus search, or in dense traffic (more than `dense_pairs` own x other
        vehicles) RM-net's (see the module doc)."""
        if own.num_vehicles * other.num_vehicles > self.dense_pairs:
            return self.rmnet(own, other, ctx)
        return super().__call__(own, other, ctx)

    def pairs_under(self, own: SharedFrame, other: SharedFrame, R: np.ndarray, t: np.ndarray,
                    descriptor_scale: float = 1.0, observed: tuple | None = None) -> np.ndarray:
        """(P, 2) RM-net's one-to-one pairs under one transform R (2, 2), t (2,) (see module doc).

        observed: the two frames' Observations when already at hand."""
        return self.rmnet.pairs_under(own, other, R, t, descriptor_scale, observed)
