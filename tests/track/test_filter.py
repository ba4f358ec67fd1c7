"""The pose filter over a simulated drive: it leaves a forced wrong track within a second."""

from __future__ import annotations

import numpy as np

from mmatch.ego.rigid import se2_to_matrix
from mmatch.evaluate import EvalConfig, prepare_scene
from mmatch.metrics import is_gross, is_success, rre_deg, rte_m
from mmatch.sequence_eval import SequenceEvalConfig, tracking_fuser
from mmatch.sim.sequences import make_sequence


def test_a_forced_wrong_track_is_left_within_one_second():
    seq = make_sequence(5, 4, 60, "hard", "wide")
    fuser = tracking_fuser(SequenceEvalConfig())
    forced_at, right_at, emitted_wrong = 12, None, 0
    for k in range(forced_at + 21):
        scene = seq.scene(k)
        own, other, _, _ = prepare_scene(scene, EvalConfig())
        if k == forced_at:        # a slide along the road by 12 m, believed 0.99
            wrong = scene.gt_T_ego_cav @ se2_to_matrix(np.eye(2), np.array([0.0, 12.0]))
            fuser.tracker.force(own, other, wrong, belief=0.99)
        res = fuser.fuse(own, other)
        if k < forced_at or res.T_ego_cav is None:
            continue
        rre, rte = rre_deg(scene.gt_T_ego_cav, res.T_ego_cav), rte_m(scene.gt_T_ego_cav, res.T_ego_cav)
        if is_success(rre, rte):
            right_at = k
            break
        emitted_wrong += is_gross(rre, rte)
    assert right_at is not None and (right_at - forced_at) * 0.05 <= 1.0, right_at
