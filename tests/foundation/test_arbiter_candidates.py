"""Which of the matcher's hypotheses the arbiter weighs beside the aligner's results (fusion.py)."""

from __future__ import annotations

import numpy as np

from mmatch.ego.base import Hypotheses, MatchResult
from mmatch.fusion import _other_hypotheses


def _rot(yaw: float) -> np.ndarray:
    return np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])


Y0, T0 = 0.3, np.array([10.0, 5.0])          # the aligner's choice
HYPS = [                                    # (yaw, t, score)
    (Y0, (10.5, 5.0), 10.0),                # the choice itself again: never weighed twice
    (Y0 + 0.01, (14.0, 5.0), 9.0),          # 4 m along: distinct, but no slide
    (Y0, (22.0, 5.0), 7.0),                 # slid 12 m
    (Y0 + np.pi, (-3.0, 1.0), 8.0),         # a flip
    (Y0 + np.pi, (-3.0, 9.0), 6.5),         # a weaker flip
    (Y0 + np.pi / 2, (0.0, 0.0), 2.0),      # a quarter turn, far below the best score
    (Y0 - np.pi / 2 + 0.05, (5.0, 5.0), 6.2),  # the other quarter turn
]


def _match() -> MatchResult:
    R = np.stack([_rot(y) for y, _, _ in HYPS])
    t = np.array([x for _, x, _ in HYPS])
    return MatchResult(hypotheses=Hypotheses(R, t, np.array([s for _, _, s in HYPS])))


def _picked(out: list) -> list[int]:
    t = np.array([x for _, x, _ in HYPS])
    return [int(np.argmin(np.linalg.norm(t - x, axis=1))) for _, x in out]


def test_the_best_distinct_hypotheses_come_first_and_each_direction_adds_its_best():
    chosen_R, chosen_t = _rot(Y0)[None], T0[None]
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 1)) == [1]
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 2)) == [1, 3]
    # per direction: the slide (2), the better flip (3), the strong quarter turn (6); the weak
    # quarter turn (5) scores below 0.6 of the best
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 1, per_direction=1)) == [1, 2, 3, 6]
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 1, per_direction=1, min_share=0.0)) \
        == [1, 2, 5, 3, 6]
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 1, per_direction=2, min_share=0.0)) \
        == [1, 2, 5, 3, 4, 6]
    # taken by the n best already: not again for its direction
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 2, per_direction=1)) == [1, 3, 2, 6]


def test_no_hypotheses_or_nothing_asked_gives_nothing():
    chosen_R, chosen_t = _rot(Y0)[None], T0[None]
    assert _other_hypotheses(MatchResult(), chosen_R, chosen_t, 3, per_direction=1) == []
    assert _other_hypotheses(_match(), chosen_R, chosen_t, 0, per_direction=0) == []
    assert _picked(_other_hypotheses(_match(), chosen_R, chosen_t, 0, per_direction=1)) == [2, 3, 6]


def test_the_arbiter_weighs_rivals_of_other_directions(hard_dir):
    """On simulated hard scenes the default arbiter weighs more candidates than the n best alone
    give it, among them some turned by a quarter turn or more from its choice. (Since the search
    weighs RM-net's pair scores, fewer rivals of other directions come within the score share:
    4 of these 16 scenes gain one, 1 of the first 8.)"""
    from mmatch.evaluate import prepare_scene
    from mmatch.fusion import Fuser, FusionConfig
    from mmatch.scene_io import load_scene

    with_dirs, without = Fuser(FusionConfig()), Fuser(FusionConfig(extra_per_direction=0))
    more, turned = 0, 0
    for f in sorted(hard_dir.glob("*.npz"))[:16]:
        own, received, _, _ = prepare_scene(load_scene(f))
        a, b = with_dirs.fuse(own, received), without.fuse(own, received)
        assert len(a.candidates) >= len(b.candidates)
        more += len(a.candidates) > len(b.candidates)
        if a.candidates:
            yaw = [np.arctan2(T[1, 0], T[0, 0]) for T, _ in a.candidates]
            turned += any(abs((y - yaw[0] + np.pi) % (2 * np.pi) - np.pi) > np.pi / 4 for y in yaw[1:])
    assert more >= 2 and turned >= 1, (more, turned)
