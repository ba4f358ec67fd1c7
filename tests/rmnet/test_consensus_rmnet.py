"""The default matcher `consensus-rmnet`: consensus's transforms, RM-net's pairs under them."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.registry import DEFAULT_MATCHER, get_matcher
from mmatch.errors import MMatchError
from mmatch.evaluate import EvalConfig, evaluate_with, prepare_scene
from mmatch.scene_io import load_scene
from mmatch.sim.generate import generate


@pytest.fixture(scope="module")
def wide_hard(tmp_path_factory):
    out = tmp_path_factory.mktemp("wide-hard")
    generate(out, 40, seed=21, mode="hard", jobs=1, physics="wide")
    return sorted(out.glob("*.npz"))


def test_is_the_default_and_registered():
    assert DEFAULT_MATCHER == "consensus-rmnet"
    m = get_matcher("consensus-rmnet")
    assert m.name == "consensus-rmnet" and m.pairs_from_transform


def test_missing_model_fails_at_start_naming_the_file(tmp_path):
    from mmatch.ego.match.consensus_rmnet import ConsensusRMNetMatcher
    from mmatch.ego.match.rmnet import RMNetConfig
    missing = tmp_path / "no-such.onnx"
    with pytest.raises(MMatchError, match="no-such.onnx"):
        ConsensusRMNetMatcher(rmnet=RMNetConfig(model_path=str(missing)))


def _fuser(name: str, matcher=None):
    """A Fuser of the named matcher, emitting everything; matcher: another instance of its kind."""
    from mmatch.ego.confidence import ConfidenceConfig
    from mmatch.fusion import FusionConfig, Fuser
    fuser = Fuser(FusionConfig(matcher=name, confidence=ConfidenceConfig(threshold=0.0)))
    if matcher is not None:
        fuser.matcher = matcher
    return fuser


def test_without_the_network_in_its_search_it_has_consensuss_transforms_and_better_pairs(wide_hard):
    """Through the CAV pipeline on wide physics, with the network's share in the search's
    likeness at 0: every scene's transform, status and confidence are consensus's; the pairs
    under them are RM-net's, and more of them are right. (The sighting polish, which refines the
    chosen transform with each matcher's own pairs, is off here: the search is compared.)"""
    from mmatch.ego.align.constrained import ConstrainedAligner, ConstrainedConfig
    from mmatch.ego.match.consensus import ConsensusConfig
    from mmatch.ego.match.consensus_rmnet import ConsensusRMNetMatcher
    counts = {"consensus": np.zeros(3), "pairs only": np.zeros(3)}
    fusers = {"consensus": _fuser("consensus"),
              "pairs only": _fuser(DEFAULT_MATCHER, ConsensusRMNetMatcher(ConsensusConfig(pair_score_share=0.0)))}
    for fuser in fusers.values():
        fuser.aligner = ConstrainedAligner(ConstrainedConfig(sighting_polish=False))
    for f in wide_hard:
        scene = load_scene(f)
        prepared = prepare_scene(scene)
        res = {}
        for name, fuser in fusers.items():
            r, fr = evaluate_with(scene, EvalConfig(confidence_threshold=0.0), fuser, prepared)
            counts[name] += (r["tp"], r["predicted"], r["gt_pairs"])
            res[name] = fr
        a, b = res["consensus"], res["pairs only"]
        assert a.status == b.status and (a.confidence == b.confidence or np.isnan(a.confidence))
        if a.T_ego_cav is not None:
            np.testing.assert_allclose(a.T_ego_cav, b.T_ego_cav)
    p0, r0, f0 = _prf(counts["consensus"])
    p1, r1, f1 = _prf(counts["pairs only"])
    # 200 wide hard scenes of seed 2: precision 0.857 -> 0.928, F1 0.877 -> 0.917; these 40
    # scenes have a few pairs in each point of precision and F1
    assert p1 > p0 + 0.04, (p0, p1)
    assert f1 > f0 + 0.01, (f0, f1)


def _prf(c):
    p, r = c[0] / c[1], c[0] / c[2]
    return p, r, 2 * p * r / (p + r)


def test_the_networks_scores_in_the_search_find_more_pairs(wide_hard):
    """The default weighs RM-net's pair scores in the consensus likeness (share 0.3): on these
    40 scenes its pairs are at least as good as without (1400 wide hard scenes of seeds 1, 3,
    4, 20-23: pair F1 0.925 -> 0.933), and a view with fewer than two vehicles has no scores."""
    from mmatch.ego.match.consensus import ConsensusConfig
    from mmatch.ego.match.consensus_rmnet import RM_NET_SHARE, ConsensusRMNetMatcher
    default = get_matcher(DEFAULT_MATCHER)
    assert default.cfg.pair_score_share == RM_NET_SHARE > 0
    assert get_matcher("consensus").cfg.pair_score_share == 0
    counts = {"share 0": np.zeros(3), "default": np.zeros(3)}
    fusers = {"share 0": _fuser(DEFAULT_MATCHER, ConsensusRMNetMatcher(ConsensusConfig(pair_score_share=0.0))),
              "default": _fuser(DEFAULT_MATCHER)}
    for f in wide_hard:
        scene = load_scene(f)
        prepared = prepare_scene(scene)
        for name, fuser in fusers.items():
            r, _ = evaluate_with(scene, EvalConfig(confidence_threshold=0.0), fuser, prepared)
            counts[name] += (r["tp"], r["predicted"], r["gt_pairs"])
        own, other = prepared[0], prepared[1]
        P = default.pair_scores(own, other)
        if own.num_vehicles < 2 or other.num_vehicles < 2:
            assert P is None
        else:
            assert P.shape == (own.num_vehicles, other.num_vehicles) and np.all((P >= 0) & (P <= 1))
    assert _prf(counts["default"])[2] >= _prf(counts["share 0"])[2] - 0.005, counts


def test_dense_frames_take_rmnets_search():
    """Above `dense_pairs` own x other vehicles the frame is RM-net's whole (its search grows with
    the square of the vehicles, consensus's with the fourth power until its budget); below it the
    consensus search runs."""
    from mmatch.ego.base import MatchContext
    from mmatch.ego.match.synthetic import dense_pair
    m = get_matcher(DEFAULT_MATCHER)
    consensus, rmnet = get_matcher("consensus"), get_matcher("rmnet")
    own, other, _, _ = dense_pair(7, 20)
    assert own.num_vehicles * other.num_vehicles > m.dense_pairs
    ctx = MatchContext(descriptor_scale=1.0)
    got, want = m(own, other, ctx), rmnet(own, other, ctx)
    np.testing.assert_array_equal(got.pairs, want.pairs)
    np.testing.assert_allclose(got.T_hint, want.T_hint)
    m.dense_pairs = own.num_vehicles * other.num_vehicles
    got, want = m(own, other, ctx), consensus(own, other, ctx)
    np.testing.assert_array_equal(got.pairs, want.pairs)
    np.testing.assert_allclose(got.T_hint, want.T_hint)


def test_each_candidates_rmnet_pairs_are_the_matchers_pairs_under_it(wide_hard):
    """RM-net's assignment under every candidate is confidence evidence (rmnet_pairs); the arbiter
    publishes the winner's. They are the matcher's `pairs_under` each candidate's transform (one
    Mahalanobis table for all the candidates, one assignment each, gives the same pairs)."""
    from mmatch.ego.observations import observations_shared, observe
    from mmatch.fusion import Fuser, FusionConfig

    fuser = Fuser(FusionConfig())
    matcher = get_matcher(DEFAULT_MATCHER)
    seen = fuser.config.confidence.observation
    compared = 0
    for f in wide_hard[:20]:
        own, other, _, _ = prepare_scene(load_scene(f))
        res = fuser.fuse(own, other)
        T = res.T_ego_cav if res.T_ego_cav is not None else res.refused_T
        if T is None:
            continue
        with observations_shared():
            observed = (observe(own, seen), observe(other, seen))
            np.testing.assert_array_equal(res.pairs, matcher.pairs_under(own, other, T[:2, :2], T[:2, 3], 1.0, observed))
            for Tc, a in res.candidates:
                if a.rmnet_pairs is not None:
                    compared += 1
                    np.testing.assert_array_equal(
                        a.rmnet_pairs, matcher.pairs_under(own, other, Tc[:2, :2], Tc[:2, 3], 1.0, observed))
    assert compared >= 20


def test_pairs_under_a_given_distance_table_are_the_pairs_computed_alone(wide_hard):
    """The arbiter hands the matchers one Mahalanobis table for all its candidates: the pairs under
    each transform are those a matcher finds computing the distances itself, one transform at a time."""
    from mmatch.ego.match.consensus import ConsensusMatcher
    from mmatch.ego.observations import mahalanobis, observe
    from mmatch.ego.rigid import rot2

    rmnet, consensus = get_matcher("rmnet"), ConsensusMatcher()
    found = 0
    for f in wide_hard[:10]:
        scene = load_scene(f)
        own, other, _, _ = prepare_scene(scene)
        observed = (observe(own), observe(other))
        if not len(observed[0].centres) or not len(observed[1].centres):
            continue
        T = scene.gt_T_ego_cav
        R = T[:2, :2] @ rot2(np.radians([0.0, 2.0, -4.0, 90.0]))
        t = T[:2, 3] + np.array([[0.0, 0.0], [1.0, -0.5], [0.0, 3.0], [0.0, 0.0]])
        dist = mahalanobis(*observed, R, t)
        many = rmnet.pairs_under_many(own, other, R, t, 1.0, observed, dist)
        for h in range(len(R)):
            np.testing.assert_array_equal(many[h], rmnet.pairs_under(own, other, R[h], t[h], 1.0, observed))
            alone = consensus.pairs_under(own, other, R[h], t[h], 1.0, observed)
            np.testing.assert_array_equal(consensus.pairs_under(own, other, R[h], t[h], 1.0, observed, dist[h]), alone)
            found += len(alone) + len(many[h])
    assert found > 0
