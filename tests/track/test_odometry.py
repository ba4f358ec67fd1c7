"""Each radar's rotation between its frames from its stationary background, and the tracker's
use of it: a turn no candidate measures is tracked at the rate the background shows."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.ego.rigid import se2_to_matrix
from mmatch.ego.track import TrackConfig, Tracker
from mmatch.ego.track.filter import Candidate, pose_of
from mmatch.ego.track.odometry import rotation
from mmatch.shared import SharedFrame

WALLS = np.vstack([np.column_stack([np.full(60, 12.0), np.linspace(-20, 90, 60)]),
                   np.column_stack([np.full(60, -12.0), np.linspace(-20, 90, 60)]),
                   np.column_stack([np.linspace(-40, 40, 50), np.full(50, 80.0)]),
                   np.array([[5.0, 30.0], [-6.0, 45.0], [8.0, 60.0], [-3.0, 20.0]])])


def _seen(world_T_radar: np.ndarray, rng: np.random.Generator, noise: float = 0.15) -> np.ndarray:
    """The walls in a radar's frame (x right, y forward), within its 60 deg either side, noisy."""
    inv = np.linalg.inv(world_T_radar)
    p = WALLS @ inv[:2, :2].T + inv[:2, 3] + rng.normal(0, noise, WALLS.shape)
    return p[(p[:, 1] > 1) & (np.abs(np.arctan2(p[:, 0], p[:, 1])) < np.radians(60))]


def _pose(x: float, y: float, heading_deg: float) -> np.ndarray:
    """A radar at (x, y) whose forward (+y) axis points heading_deg counter-clockwise of world +y."""
    a = np.radians(heading_deg)
    return se2_to_matrix(np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]), np.array([x, y]))


@pytest.mark.parametrize("turn_deg", [0.0, 2.5, -4.0, 7.0])
def test_a_radars_rotation_between_two_frames_comes_from_its_background(turn_deg):
    """A radar driving at 10 m/s turns by turn_deg in 0.1 s: the background turns the other way
    by as much; measured within 0.3 deg (points with 0.15 m noise), whatever the guess within
    the search's span, with an honest spread (0.5 deg at least)."""
    rng = np.random.default_rng(3)
    v = np.array([0.0, 10.0])
    dt, phi = 0.1, np.radians(turn_deg)
    d = np.array([-np.sin(phi / 2), np.cos(phi / 2)]) * 10.0 * dt        # R(phi / 2) v dt
    before, after = _pose(0.0, 0.0, 0.0), _pose(*d, turn_deg)
    v_after = v                                                          # its own frame: still forward
    for guess in (0.0, phi):
        got = rotation(_seen(before, rng), _seen(after, rng), v, v_after, dt, guess)
        assert got is not None
        assert abs(np.degrees(got[0]) - turn_deg) < 0.3
        assert np.radians(0.5) - 1e-12 <= got[1] < np.radians(2.0)


def test_a_turn_across_a_gap_in_the_frames_is_searched_as_wide_as_the_gap_allows():
    """Frames 0.4 s apart (a radio dropping some): a turn at 45 deg/s that began in the gap moved
    the radar 18 deg, twice the search around the track's guess of no turn; the search widens
    with the time elapsed (60 deg/s x dt). Without that, on drives of seed 500 with 0.4 s of
    frames removed, a wrong rotation published a turning CAV 12-13 deg off for 19 frames."""
    rng = np.random.default_rng(6)
    v, dt, phi = np.array([0.0, 10.0]), 0.4, np.radians(18.0)
    d = np.array([-np.sin(phi / 2), np.cos(phi / 2)]) * 10.0 * dt
    got = rotation(_seen(_pose(0.0, 0.0, 0.0), rng), _seen(_pose(*d, 18.0), rng), v, v, dt, 0.0)
    assert got is not None and abs(np.degrees(got[0]) - 18.0) < 0.5


def test_a_sender_s_largest_background_is_thinned_and_still_measured():
    """4096 background points (the wire's cap) are thinned to about 600 before the search: the
    rotation is found as from the full set."""
    rng = np.random.default_rng(8)
    before, after = _seen(_pose(0.0, 0.0, 0.0), rng), _seen(_pose(-0.05, 1.0, 3.0), rng)
    dense_before = np.repeat(before, int(np.ceil(4096 / len(before))), axis=0)[:4096] + rng.normal(0, 0.05, (4096, 2))
    dense_after = np.repeat(after, int(np.ceil(4096 / len(after))), axis=0)[:4096] + rng.normal(0, 0.05, (4096, 2))
    v = np.array([0.0, 10.0])
    got = rotation(dense_before, dense_after, v, v, 0.1)
    assert got is not None and abs(np.degrees(got[0]) - 3.0) < 0.5


def test_too_sparse_a_background_measures_nothing():
    rng = np.random.default_rng(4)
    sparse = _seen(_pose(0, 0, 0), rng)[:10]
    assert rotation(sparse, sparse, np.zeros(2), np.zeros(2), 0.05) is None
    full = _seen(_pose(0, 0, 0), rng)
    assert rotation(full, full, np.zeros(2), np.zeros(2), 0.0) is None          # no time elapsed


def _frame(sender: str, stamp: float, velocity: np.ndarray, background: np.ndarray) -> SharedFrame:
    return SharedFrame(sender, 0, stamp, 0.5, ego_velocity=np.asarray(velocity, float),
                       background=np.c_[background, np.zeros(len(background))].astype(np.float32))


def _coast_through_a_turn(cfg: TrackConfig, rate_hz: float) -> float:
    """The Ego stands still; the CAV, 30 m ahead, drives at 8 m/s and turns at 35 deg/s after
    three frames that start a believed track; no frame after them has a candidate. Returns the
    tracked yaw's error (deg) after 1.2 s of the turn."""
    rng = np.random.default_rng(5)
    tr = Tracker(cfg)
    ego = _pose(0.0, 0.0, 0.0)
    w, speed, dt = np.radians(35.0), 8.0, 1.0 / rate_hz
    pos, heading = np.array([0.0, 30.0]), 0.0
    t, err = 0.0, np.nan
    for k in range(3 + int(round(1.2 * rate_hz))):
        turning = k >= 3
        cav = _pose(*pos, np.degrees(heading))
        own = _frame("ego", t, np.zeros(2), _seen(ego, rng))
        oth = _frame("cav", t, np.array([0.0, speed]), _seen(cav, rng))
        pred = tr.predict(own, oth)
        truth = np.linalg.inv(ego) @ cav
        cands = [] if turning else [Candidate(pose_of(truth), np.diag([0.2, 0.2, np.radians(0.5)]) ** 2, 0.95)]
        best, _ = tr.commit(own, oth, pred, cands, full_search=not turning)
        err = float(np.degrees(abs(np.angle(np.exp(1j * (best.x[2] - pose_of(truth)[2]))))))
        # the next frame: turn about the radar (no lever arm), moving along the mid-interval heading
        step = w * dt if k >= 2 else 0.0
        mid = heading + step / 2
        pos = pos + speed * dt * np.array([-np.sin(mid), np.cos(mid)])
        heading, t = heading + step, t + dt
    return err


@pytest.mark.parametrize("rate_hz", [20.0, 10.0])
def test_a_turn_no_candidate_measures_is_tracked_at_the_rate_the_background_shows(rate_hz):
    """Without odometry (and without the lever-arm bound, which a radar over its turning centre
    cannot give) the track keeps the yaw rate it had and ends 40 deg off; with it, within 3 deg."""
    with_odometry = _coast_through_a_turn(TrackConfig(lever_arm_m=0.0), rate_hz)
    without = _coast_through_a_turn(TrackConfig(lever_arm_m=0.0, odometry=None), rate_hz)
    assert with_odometry < 3.0
    assert without > 30.0
