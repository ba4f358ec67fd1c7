"""The `rmnet` matcher: RM-net proposes, geometry verifies, within a time budget."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.base import MatchContext
from mmatch.ego.match import rmnet as rm
from mmatch.ego.match.synthetic import dense_pair
from mmatch.ego.registry import get_matcher
from mmatch.metrics import is_success, pair_counts, rre_deg, rte_m

from .conftest import make_frame


@pytest.fixture(scope="module")
def matcher():
    return rm.RMNetMatcher()


def test_views_with_zero_or_one_vehicle_give_no_pairs(matcher):
    two = make_frame([[0, 10], [3, 25]])
    for few in (make_frame(np.zeros((0, 2))), make_frame([[1, 12]])):
        for own, other in ((few, two), (two, few), (few, few)):
            res = matcher(own, other, MatchContext())
            assert len(res.pairs) == 0 and res.T_hint is None


def test_registered():
    for name in ("rmnet", "rmnet-only", "geometry", "descriptor"):
        assert get_matcher(name).name == name


def test_prune_keeps_top_k_of_each_vehicle():
    P = np.array([[0.9, 0.5, 0.1, 0.01],
                  [0.2, 0.3, 0.8, 0.05],
                  [0.6, 0.0, 0.0, 0.0]])
    cand = {tuple(c) for c in rm.prune(P, 1, 0.02).tolist()}
    # row bests (0,0) (1,2) (2,0); column bests (0,0) (0,1) (1,2) (1,3)
    assert cand == {(0, 0), (1, 2), (2, 0), (0, 1), (1, 3)}
    assert (2, 1) not in {tuple(c) for c in rm.prune(P, 3, 0.02).tolist()}     # below min_prob


def test_hypotheses_grow_with_the_square_of_the_vehicles():
    cfg = rm.RMNetConfig()
    counts = {}
    rng = np.random.default_rng(0)
    for V in (10, 20, 40):
        A = rng.uniform(-30, 30, (V, 2))
        P = rng.random((V, V))
        cand = rm.prune(P, cfg.top_k, cfg.min_prob)
        R, _ = rm.hypotheses(A, A, cand, P[cand[:, 0], cand[:, 1]], None, cfg)
        counts[V] = len(R)
        assert len(cand) <= 2 * cfg.top_k * V
        assert len(R) <= min(cfg.seeds * len(cand), cfg.max_hypotheses)
    assert counts[40] < 6 * counts[20]                 # quadruple would be 16x; capped and pruned


def test_a_crossing_roads_band_admits_oblique_two_pair_hypotheses():
    """Two vehicles seen by both views, the CAV turned 60 deg (an oblique crossing): the yaw gate
    drops the two-pair hypothesis unless the crossing candidates' band is given."""
    cfg = rm.RMNetConfig()
    a = np.radians(60.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    B = np.array([[2.0, 20.0], [-4.0, 35.0]])
    A = B @ R.T + [5.0, 8.0]
    cand = np.array([[0, 0], [1, 1]])
    w = np.ones(2)
    yaws = np.radians([0.0, 90.0, 180.0, 270.0])                  # the right-angle candidates
    allow = np.radians(35.0) * (np.arange(4) % 2)

    def found(allowance):
        Rs, ts = rm.hypotheses(A, B, cand, w, yaws, cfg, allowance)
        yaw = np.degrees(np.arctan2(Rs[:, 1, 0], Rs[:, 0, 0]))
        return bool(np.any((np.abs(yaw - 60.0) < 0.5) & (np.linalg.norm(ts - [5.0, 8.0], axis=1) < 0.1)))

    assert not found(None) and found(allow)


def test_finds_the_transform_and_pairs_in_dense_traffic(matcher):
    own, other, gt, T = dense_pair(7, 20)
    res = matcher(own, other, MatchContext(descriptor_scale=1.0))
    assert res.T_hint is not None and is_success(rre_deg(T, res.T_hint), rte_m(T, res.T_hint))
    tp, pred, n = pair_counts(res.pairs, gt)
    assert tp >= 0.8 * n and tp >= 0.8 * pred


def test_past_the_budget_returns_the_best_coarse_answer(monkeypatch):
    own, other, gt, T = dense_pair(7, 20)

    def no_refinement(*args, **kwargs):
        raise AssertionError("refinement ran past the budget")

    monkeypatch.setattr(rm, "refine_many", no_refinement)
    res = rm.RMNetMatcher(rm.RMNetConfig(budget_ms=0.0))(own, other, MatchContext(descriptor_scale=1.0))
    assert res.T_hint is not None                        # coarse, verified on the candidates
    assert rte_m(T, res.T_hint) < 5.0


def test_nothing_verified_is_no_estimate(matcher):
    # two views of unrelated vehicles far apart in appearance: no transform explains anything
    own = make_frame([[0, 10], [30, 80]], seed=1)
    other = make_frame([[5, 60], [-40, 12]], seed=2)
    res = rm.verify(own, other, MatchContext(), np.zeros((2, 2)), *(matcher.probabilities(own, other)[1:]),
                    rm.RMNetConfig(), 0.0)
    assert res.T_hint is None and len(res.pairs) == 0


def test_ablation_matchers_give_one_to_one_pairs():
    own, other, gt, T = dense_pair(3, 12)
    for name in ("rmnet-only", "descriptor", "geometry"):
        res = get_matcher(name)(own, other, MatchContext(descriptor_scale=1.0))
        assert len(np.unique(res.pairs[:, 0])) == len(res.pairs) == len(np.unique(res.pairs[:, 1]))
