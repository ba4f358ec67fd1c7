"""The constrained aligner's `polish`: the vehicles' sightings of each other pin a slide along
the street that two co-visible vehicles and a straight roadside leave loose."""

from __future__ import annotations

import dataclasses

import numpy as np

from mmatch.ego.align.constrained import ConstrainedAligner, ConstrainedConfig
from mmatch.ego.base import far_side_centres
from mmatch.fusion import Fuser
from tests.report.synth import T_se2, frame

T_TRUE = T_se2(0.0, 0.0, 20.0)        # the CAV drives 20 m ahead of the Ego in its lane
PAIRS = np.array([[0, 0], [1, 1]], np.int32)
SLIDE_M = 3.0                          # how far along the street the CAV places both shared cars


def _frames(cav_doppler: float = 0.0, ego_sees_cav: bool = True, bus: bool = False):
    """Ego and CAV frames of a street with two shared cars ahead and no background; the CAV's
    view of both is SLIDE_M further along the street than the truth (as a wrong far-side shift
    would put them), so the pairs alone prefer a slid transform.
    The Ego also detects the CAV itself (third vehicle, its body centre 2.3 m behind its radar),
    with `cav_doppler` (m/s) on its returns: 0 moves as the Ego does, as the CAV does. bus: the
    CAV is a bus in a box 3.4 m tall, the centre the Ego estimates for it (`far_side_centres`)
    4.8 m behind its radar."""
    rng = np.random.default_rng(4)
    nothing = np.zeros((0, 2))             # no roadside return holds the slide along the street
    shared = np.array([[3.0, 40.0], [-3.0, 55.0]])
    cav_body = T_TRUE[:2, 3] + [0.0, -2.3]
    ego_cars = np.vstack([shared, cav_body]) if ego_sees_cav else shared
    own = frame("ego", nothing, ego_cars, np.eye(4), rng)
    if ego_sees_cav:
        pts = own.vehicle_points.copy()
        pts[own.vehicle_index == 2, 3] = cav_doppler
        own = dataclasses.replace(own, vehicle_points=pts)
        if bus:                                         # 170 canonical px at 20 m: 3.4 m tall
            boxes = own.vehicle_boxes.copy()
            boxes[2, 3] = boxes[2, 1] + 170.0
            own = dataclasses.replace(own, vehicle_boxes=boxes)
            move = T_TRUE[:2, 3] + [0.0, -4.8] - far_side_centres(own)[2]
            pts[own.vehicle_index == 2, :2] += move.astype(np.float32)
            own = dataclasses.replace(own, vehicle_points=pts)
    other = frame("cav", nothing, shared + [0.0, SLIDE_M], np.linalg.inv(T_TRUE), rng)
    return own, other


def _slid_start():
    """Where the pairs put the CAV: SLIDE_M short of the truth along the street."""
    return T_se2(0.0, 0.0, 20.0 - SLIDE_M)


def _untouched(result, T0) -> bool:
    T, info = result
    return T is T0 and info is None


def test_a_sighting_pulls_the_slide_along_the_street_back():
    own, other = _frames()
    T0 = _slid_start()
    T, info = ConstrainedAligner().polish(own, other, PAIRS, T0)
    before, after = abs(T0[1, 3] - T_TRUE[1, 3]), abs(T[1, 3] - T_TRUE[1, 3])
    assert before == SLIDE_M
    assert after < before - 0.5                      # one sighting against two pairs that agree
    assert abs(T[0, 3]) < 0.3 and abs(np.arctan2(T[1, 0], T[0, 0])) < np.radians(1.0)
    # what the sighting tells, (x, y, yaw): the CAV's body seen 17.7 m ahead along y, across its
    # line of sight (x) best, along it (y) at the detection's along-ray spread and the body's
    assert np.allclose(info, info.T) and np.all(np.linalg.eigvalsh(info) >= -1e-12)
    assert info[0, 0] > info[1, 1] > 0.2


def test_without_a_sighting_the_transform_is_left_alone():
    own, other = _frames(ego_sees_cav=False)
    T0 = _slid_start()
    assert _untouched(ConstrainedAligner().polish(own, other, PAIRS, T0), T0)


def test_a_detection_moving_otherwise_than_the_cav_is_not_the_cav():
    own, other = _frames(cav_doppler=-10.0)          # standing still while both radars drive at 10 m/s
    T0 = _slid_start()
    assert _untouched(ConstrainedAligner().polish(own, other, PAIRS, T0), T0)


def test_polish_can_be_switched_off():
    own, other = _frames()
    T0 = _slid_start()
    aligner = ConstrainedAligner(ConstrainedConfig(sighting_polish=False))
    assert _untouched(aligner.polish(own, other, PAIRS, T0), T0)


def test_a_matched_vehicle_is_never_taken_for_the_other_vehicle():
    own, other = _frames()
    T0 = _slid_start()
    # the Ego's detection of the CAV matched to a CAV vehicle: it is a shared car, not a sighting
    pairs = np.array([[0, 0], [2, 1]], np.int32)
    assert _untouched(ConstrainedAligner().polish(own, other, pairs, T0), T0)


def test_the_fuser_publishes_the_polished_transform():
    own, other = _frames()
    fuser = Fuser()
    calls = []
    real = fuser.aligner.polish

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        calls.append(out)
        return out

    fuser.aligner.polish = spy
    res = fuser.fuse(own, other)
    assert len(calls) == 1
    polished, info = calls[0]
    assert info is not None
    T = res.T_ego_cav if res.T_ego_cav is not None else res.refused_T
    assert T is polished
    chosen = [ac for Tc, ac in res.candidates if Tc is polished]
    assert len(chosen) == 1 and chosen[0].covariance is res.covariance
    # the sighting's information narrows the published covariance: it is not the fit's alone
    fuser.aligner.polish = lambda own, other, pairs, T, *rest: (T, None)
    plain = fuser.fuse(own, other)
    assert np.linalg.det(res.covariance) < np.linalg.det(plain.covariance)



def test_equal_hypotheses_are_ranked_by_where_they_put_the_other_radar():
    """The search's order of its hypotheses does not depend on the order they came in (which is
    the order of the detections): equal ranks by the translation."""
    from mmatch.ego.match.consensus import best_first
    rng = np.random.default_rng(1)
    rank = rng.integers(0, 4, 60).astype(float)           # many ties, as sighting hypotheses give
    t = rng.normal(0, 20, (60, 2))
    first = t[best_first(rank, t)]
    for _ in range(5):
        p = rng.permutation(60)
        np.testing.assert_array_equal(t[p][best_first(rank[p], t[p])], first)
    assert np.all(np.diff(rank[best_first(rank, t)]) <= 0)


def test_a_tall_detection_puts_its_radar_farther_ahead():
    """A bus's or lorry's radar sits farther ahead of the centre a view estimates for it than a
    car's (SightingModel): the Ego that follows a bus places the CAV where it is, not 2.5 m short."""
    from mmatch.ego.base import SightingModel

    own, other = _frames(bus=True)
    model = SightingModel()
    assert model.long(own).tolist() == [False, False, True]
    assert model.offsets(own).tolist() == [model.body_offset_m, model.body_offset_m, model.long_offset_m]
    assert model.sigmas(own)[2] > model.sigmas(own)[0]
    assert abs(far_side_centres(own)[2][1] - (T_TRUE[1, 3] - 4.8)) < 0.05
    T0 = _slid_start()
    T, info = ConstrainedAligner().polish(own, other, PAIRS, T0)
    assert info is not None and abs(T[1, 3] - T_TRUE[1, 3]) < SLIDE_M - 0.5
    # read as a car, the same detection puts the CAV's radar 2.5 m short of the truth: the
    # sighting would hold the slide instead of pulling it back
    as_car = ConstrainedConfig(sighting=dataclasses.replace(model, long_height_m=10.0))
    T_car, _ = ConstrainedAligner(as_car).polish(own, other, PAIRS, T0)
    assert abs(T_car[1, 3] - T_TRUE[1, 3]) > abs(T[1, 3] - T_TRUE[1, 3]) + 0.5
