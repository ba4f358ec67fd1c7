"""Appearance augmentation of training graphs: the rewritten graph is the graph of the rewritten descriptors."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mmatch.ego.match.graph import build_graph
from mmatch.train.augment import AppearanceAugment, augment
from mmatch.train.data import sample_from_frames

from .conftest import make_frame


def _sample():
    own = make_frame([[0, 10], [3, 25], [-4, 40], [6, 18]], seed=1)
    other = make_frame([[1, 12], [-2, 30], [5, 22]], seed=2)
    return own, other, sample_from_frames(own, other, np.array([[0, 0], [1, 1]]))


def test_without_augmentation_a_sample_is_left_alone():
    _, _, s = _sample()
    assert augment(s, AppearanceAugment(p=0.0), np.random.default_rng(0)) is s


def test_augmented_features_are_those_of_the_rewritten_descriptors():
    """Nodes and local edges of an augmented sample equal the graph built from frames that carry
    the augmented descriptors (the histograms are the squares of the embedding); geometry and
    the target stay as they were."""
    own, other, s = _sample()
    changed = 0
    for seed in range(6):
        a = augment(s, AppearanceAugment(p=1.0), np.random.default_rng(seed))
        rebuilt = build_graph(replace(own, vehicle_features=(a.xa[:, :32] ** 2).astype(np.float32)),
                              replace(other, vehicle_features=(a.xb[:, :32] ** 2).astype(np.float32)))
        for x, e, g in ((a.xa, a.ea, rebuilt.own), (a.xb, a.eb, rebuilt.other)):
            np.testing.assert_allclose(x, g.nodes, atol=1e-5)
            np.testing.assert_allclose(e, g.edges, atol=1e-5)
        np.testing.assert_array_equal(a.xa[:, 32:], s.xa[:, 32:])
        np.testing.assert_array_equal(a.eb[..., :9], s.eb[..., :9])
        np.testing.assert_array_equal(a.target, s.target)
        changed += int(not np.allclose(a.xa[:, :32], s.xa[:, :32]) or not np.allclose(a.xb[:, :32], s.xb[:, :32]))
    assert changed == 6


def test_a_hue_turn_moves_one_view_only_and_keeps_the_histograms_whole():
    _, _, s = _sample()
    cfg = AppearanceAugment(p=1.0, max_mix=0.0, max_hue_bins=1.0)
    a = augment(s, cfg, np.random.default_rng(3))
    moved = [not np.allclose(a.xa[:, :16], s.xa[:, :16]), not np.allclose(a.xb[:, :16], s.xb[:, :16])]
    assert sorted(moved) == [False, True]
    for x in (a.xa, a.xb):                          # unit length per H, S, V group, as the embedding is
        for lo, hi in ((0, 16), (16, 24), (24, 32)):
            np.testing.assert_allclose(np.linalg.norm(x[:, lo:hi], axis=1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(a.xa[:, 16:32], s.xa[:, 16:32], atol=1e-6)   # saturation and value untouched
    np.testing.assert_allclose(a.xb[:, 16:32], s.xb[:, 16:32], atol=1e-6)
