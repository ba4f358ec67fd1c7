"""The paper's alignment, its ICP ablation and the point-cloud peers on exact synthetic frames."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from mmatch.ego.align import paper as paper_module
from mmatch.ego.align.grouped_icp import PointSet, grouped_icp
from mmatch.ego.base import MatchResult
from mmatch.ego.registry import get_aligner, get_matcher
from mmatch.errors import ConfigError
from mmatch.metrics import rre_deg, rte_m
from tests.report.synth import T_se2, pair_of_frames

TRUE_PAIRS = np.array([[0, 0], [1, 1], [2, 2], [3, 3]], np.int32)


def _match(pairs=TRUE_PAIRS, scores=None):
    return MatchResult(pairs=pairs, scores=np.ones(len(pairs)) if scores is None else scores)


@pytest.mark.parametrize("name", ["icp-all", "icp-bg", "icp-veh", "icp-pair", "paper"])
def test_pair_started_aligners_recover_the_transform(name):
    T = T_se2(25.0, 6.0, -14.0)
    own, other = pair_of_frames(T)
    res = get_aligner(name)(own, other, _match())
    assert res.T is not None
    assert rre_deg(T, res.T) < 1.0 and rte_m(T, res.T) < 0.5
    assert res.T[2, 3] == pytest.approx(0.0) and res.T[2, 2] == 1.0


@pytest.mark.parametrize("name", ["icp-all", "icp-bg", "icp-veh", "icp-pair", "paper"])
def test_pair_started_aligners_need_two_pairs(name):
    own, other = pair_of_frames(T_se2(10.0, 1.0, 2.0))
    res = get_aligner(name)(own, other, _match(TRUE_PAIRS[:1]))
    assert res.T is None and "1 matched vehicle" in res.reason


def test_grouped_icp_pairs_points_only_inside_their_group():
    rng = np.random.default_rng(3)
    a = rng.uniform(-5, 5, (40, 2))
    b = a + [0.9, 0.0]                         # every point also lies 0.9 m from a neighbour of the other group
    dst = np.vstack([a, b])
    g_dst = np.repeat([0, 1], 40)
    src = dst - [2.0, 1.0]                     # true t = (2, 1)
    free = PointSet.ungrouped(src, dst, 4.0, 4.0)
    grouped = PointSet(src, dst, g_dst, g_dst, np.ones(80), 4.0, 4.0)
    _, t_free, _ = grouped_icp([free], np.eye(2), np.zeros(2))
    R, t, inl = grouped_icp([grouped], np.eye(2), np.zeros(2))
    assert np.allclose(t, [2.0, 1.0], atol=1e-6) and np.allclose(R, np.eye(2), atol=1e-9)
    assert inl == 1.0
    assert not np.allclose(t_free, [2.0, 1.0], atol=1e-3)


def test_paper_weights_are_exp_score_and_exp_one_over_nv(monkeypatch):
    seen: list[list[PointSet]] = []
    real = paper_module.grouped_icp

    def spy(sets, R, t, iterations=30):
        seen.append(sets)
        return real(sets, R, t, iterations)

    monkeypatch.setattr(paper_module, "grouped_icp", spy)
    own, other = pair_of_frames(T_se2(5.0, 2.0, 3.0))
    pairs = TRUE_PAIRS[:3]
    scores = np.array([0.2, 0.5, 0.9])
    assert get_aligner("paper")(own, other, _match(pairs, scores)).T is not None
    stage1, stage2 = seen
    assert len(stage1) == 1 and len(stage2) == 2
    veh = stage1[0]
    assert np.allclose(veh.weight, np.exp(scores)[veh.src_group])
    assert set(np.unique(veh.src_group)) == {0, 1, 2}
    assert np.allclose(stage2[1].weight, np.exp(1.0 / 3))
    assert len(stage2[1].src) == len(other.background)


def test_none_matcher_finds_nothing():
    own, other = pair_of_frames(np.eye(4))
    m = get_matcher("none")(own, other, None)
    assert len(m.pairs) == 0 and m.T_hint is None


def test_gicp_peer_recovers_a_small_offset_as_se2():
    pytest.importorskip("small_gicp")
    T = T_se2(2.0, 0.6, -0.4)
    own, other = pair_of_frames(T)
    res = get_aligner("gicp")(own, other, MatchResult())
    assert res.T is not None and res.T[2, 2] == 1.0
    assert rre_deg(T, res.T) < 0.5 and rte_m(T, res.T) < 0.2


@pytest.mark.parametrize("name", ["o3d-icp", "o3d-fgr", "o3d-ransac"])
def test_open3d_peers_recover_a_small_offset(name):
    pytest.importorskip("open3d", reason="the Open3D peers need the baselines extra (open3d-cpu)")
    T = T_se2(2.0, 0.6, -0.4)
    own, other = pair_of_frames(T)
    res = get_aligner(name)(own, other, MatchResult())
    assert res.T is not None and res.T[2, 2] == 1.0
    assert rre_deg(T, res.T) < 1.0 and rte_m(T, res.T) < 0.5


def test_a_missing_library_names_the_install_line(monkeypatch):
    from mmatch.ego.align.baselines import missing_extra
    monkeypatch.setitem(sys.modules, "open3d", None)
    monkeypatch.setitem(sys.modules, "small_gicp", None)
    for name in ("o3d-icp", "gicp"):
        assert "pip install 'mmatch[baselines]'" in missing_extra(name)
        with pytest.raises(ConfigError, match="baselines"):
            get_aligner(name)
    assert missing_extra("constrained") is None
