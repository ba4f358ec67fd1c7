"""Appearance augmentation of training batches: each rewritten graph is the graph of its rewritten descriptors."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mmatch.ego.match.graph import build_graph
from mmatch.train.augment import AppearanceAugment, augment_batch
from mmatch.train.data import collate_arrays, sample_from_frames

from .conftest import make_frame


def _batch():
    """Two frame pairs of different sizes (the smaller one padded), with their frames."""
    pairs = [(make_frame([[0, 10], [3, 25], [-4, 40], [6, 18]], seed=1), make_frame([[1, 12], [-2, 30], [5, 22]], seed=2)),
             (make_frame([[2, 15], [-3, 28]], seed=3), make_frame([[0, 20], [4, 35], [-5, 12], [1, 44], [7, 9]], seed=4))]
    samples = [sample_from_frames(a, b, np.array([[0, 0], [1, 1]])) for a, b in pairs]
    return pairs, samples, collate_arrays(samples)


def test_without_augmentation_a_batch_is_left_alone():
    _, _, arrays = _batch()
    before = {k: v.copy() for k, v in arrays.items()}
    augment_batch(arrays, AppearanceAugment(p=0.0), np.random.default_rng(0))
    for k, v in before.items():
        np.testing.assert_array_equal(arrays[k], v)


def test_augmented_features_are_those_of_the_rewritten_descriptors():
    """Each graph's nodes and local edges after the rewrite equal the graph built from frames that
    carry the rewritten descriptors (the histograms are the squares of the embedding); geometry,
    targets and the padding stay as they were."""
    pairs, samples, clean = _batch()
    changed = 0
    for seed in range(5):
        arrays = {k: v.copy() for k, v in clean.items()}
        augment_batch(arrays, AppearanceAugment(p=1.0), np.random.default_rng(seed))
        for k, ((own, other), s) in enumerate(zip(pairs, samples)):
            va, vb, ka, kb = len(s.xa), len(s.xb), s.ea.shape[1], s.eb.shape[1]
            xa, xb = arrays["xa"][k, :va], arrays["xb"][k, :vb]
            g = build_graph(replace(own, vehicle_features=(xa[:, :32] ** 2).astype(np.float32)),
                            replace(other, vehicle_features=(xb[:, :32] ** 2).astype(np.float32)))
            np.testing.assert_allclose(xa, g.own.nodes, atol=1e-5)
            np.testing.assert_allclose(xb, g.other.nodes, atol=1e-5)
            np.testing.assert_allclose(arrays["ea"][k, :va, :ka], g.own.edges, atol=1e-5)
            np.testing.assert_allclose(arrays["eb"][k, :vb, :kb], g.other.edges, atol=1e-5)
            np.testing.assert_array_equal(xa[:, 32:], s.xa[:, 32:])
            changed += int(not np.allclose(xa[:, :32], s.xa[:, :32]) or not np.allclose(xb[:, :32], s.xb[:, :32]))
        for key in ("xa", "xb", "ea", "eb"):           # padding stays zero
            assert not arrays[key][0 if key.endswith("b") else 1, 3 if key.endswith("b") else 2:].any()
        np.testing.assert_array_equal(arrays["target"], clean["target"])
    assert changed == 10


def test_a_hue_turn_moves_one_view_only_and_keeps_the_histograms_whole():
    _, samples, clean = _batch()
    arrays = {k: v.copy() for k, v in clean.items()}
    augment_batch(arrays, AppearanceAugment(p=1.0, max_mix=0.0, max_hue_bins=1.0), np.random.default_rng(3))
    for k, s in enumerate(samples):
        xa, xb = arrays["xa"][k, :len(s.xa)], arrays["xb"][k, :len(s.xb)]
        moved = [not np.allclose(xa[:, :16], s.xa[:, :16]), not np.allclose(xb[:, :16], s.xb[:, :16])]
        assert sorted(moved) == [False, True]
        for x, orig in ((xa, s.xa), (xb, s.xb)):
            for lo, hi in ((0, 16), (16, 24), (24, 32)):          # unit length per H, S, V group
                np.testing.assert_allclose(np.linalg.norm(x[:, lo:hi], axis=1), 1.0, rtol=1e-5)
            np.testing.assert_allclose(x[:, 16:32], orig[:, 16:32], atol=1e-6)   # saturation, value untouched
