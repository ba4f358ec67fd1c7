"""Frustum separation: projection, the box / wedge / depth-window rules, one owner per point."""

from __future__ import annotations

import numpy as np

from mmatch.cav.config import SeparationConfig
from mmatch.cav.frustum import centres_from_boxes, project, separate

from .synth import make_camera

CAM = make_camera()     # f = 800 px, principal point (640, 360), camera 0.3 m above the radar


def box_around(x, y, half_w=1.0, depth=None, z_lo=-0.8, z_hi=0.7, score=0.9):
    """The pixel box of a radar-frame BEV extent around (x, y), with a depth."""
    corners = np.array([[x + dx, y, z] for dx in (-half_w, half_w) for z in (z_lo, z_hi)])
    pr = project(corners, CAM)
    u1, v1 = pr.uv.min(0)
    u2, v2 = pr.uv.max(0)
    d = np.hypot(x, y) if depth is None else depth
    return np.array([u1, v1, u2, v2, score, d], np.float32)


def test_projection_of_known_points():
    pr = project(np.array([[0.0, 10.0, 0.3], [2.0, 20.0, 0.3], [0.0, -5.0, 0.0]]), CAM)
    np.testing.assert_allclose(pr.uv[0], [640, 360], atol=1e-9)
    np.testing.assert_allclose(pr.uv[1], [640 + 800 * 2 / 20, 360], atol=1e-9)
    assert pr.front.tolist() == [True, True, False]
    assert np.all(np.isnan(pr.uv[2]))
    np.testing.assert_allclose(pr.bev_range[1], np.hypot(2, 20))


def test_box_points_near_depth_are_claimed_far_ones_are_not():
    box = box_around(0.0, 20.0)
    pts = np.array([[0.2, 19.5, 0.0],     # in box, near depth, stationary -> claimed
                    [0.2, 40.0, 0.0],     # in box, far behind -> not
                    [0.2, 21.0, 8.0],     # right depth, far above the box, stationary -> not
                    [0.2, 21.0, 8.0],     # same place but moving: in the wedge -> claimed
                    [9.0, 20.0, 0.0]],    # outside the wedge, moving -> not
                   np.float32)
    moving = np.array([False, False, False, True, True])
    sep = separate(pts, moving, box[None], CAM)
    assert sep.owner.tolist() == [0, -1, -1, 0, -1]
    assert sep.claimed.tolist() == [2] and sep.claimed_moving.tolist() == [1]


def test_moving_points_have_a_wider_depth_window():
    box = box_around(0.0, 40.0, depth=30.0)          # detector under-estimates depth by 25 %
    pts = np.array([[0.0, 40.0, 0.0], [0.0, 40.0, 0.0]], np.float32)
    sep = separate(pts, np.array([True, False]), box[None], CAM,
                   SeparationConfig(delta_d_m=1.0, depth_rel=0.1, moving_depth_rel=0.35))
    assert sep.owner.tolist() == [0, -1]


def test_a_point_goes_to_the_box_nearest_in_depth():
    near, far = box_around(0.0, 15.0, half_w=1.5), box_around(0.0, 25.0, half_w=2.5)
    pts = np.array([[0.0, 16.0, 0.0], [0.0, 23.0, 0.0], [0.0, 19.0, 0.0]], np.float32)
    sep = separate(pts, np.ones(3, bool), np.stack([near, far]), CAM,
                   SeparationConfig(delta_d_m=6.0, depth_rel=0.0, moving_depth_rel=0.0))
    assert sep.owner.tolist() == [0, 1, 0]


def test_low_score_boxes_are_ignored():
    box = box_around(0.0, 20.0, score=0.2)
    sep = separate(np.array([[0.0, 20.0, 0.0]], np.float32), np.array([True]), box[None], CAM,
                   SeparationConfig(min_box_score=0.5))
    assert sep.owner.tolist() == [-1] and sep.active.tolist() == [False]


def test_box_clipped_at_the_image_edge_opens_its_wedge():
    box = np.array([1100, 300, 1279, 420, 0.9, 12.0], np.float32)    # touches the right edge
    pts = np.array([[9.5, 7.0, 0.0]], np.float32)                      # 53 deg right: outside the image
    assert project(pts, CAM).uv[0, 0] > 1280
    sep = separate(pts, np.array([True]), box[None], CAM)
    assert sep.owner.tolist() == [0]


def test_empty_inputs():
    sep = separate(np.zeros((0, 5), np.float32), np.zeros(0, bool), np.zeros((2, 6), np.float32), CAM)
    assert sep.owner.shape == (0,) and sep.claimed.tolist() == [0, 0]
    sep = separate(np.ones((3, 5), np.float32), np.ones(3, bool), np.zeros((0, 6), np.float32), CAM)
    assert sep.owner.tolist() == [-1, -1, -1]


def test_centre_from_box_bearing_and_depth():
    for x, y in [(0.0, 20.0), (-6.0, 30.0), (8.0, 15.0)]:
        box = box_around(x, y, half_w=0.9)
        cam_xy = np.array([0.0, 0.0])          # the camera sits above the radar
        box[5] = np.hypot(x - cam_xy[0], y - cam_xy[1])
        np.testing.assert_allclose(centres_from_boxes(box[None], CAM)[0], [x, y], atol=0.05)
    assert centres_from_boxes(np.zeros((0, 6)), CAM).shape == (0, 2)


def test_grow_adopts_a_vehicle_return_pushed_just_outside_its_wedge():
    from mmatch.cav.frustum import grow

    cfg = SeparationConfig(grow_eps_m=3.0, grow_margin_deg=2.0)
    box = box_around(0.0, 30.0, half_w=1.0)
    # two returns inside the wedge; one 1.6 m to the side (3 deg: azimuth noise); one far
    # off to the side; one in reach but of another speed; one stationary
    pts = np.array([[0.3, 29.0, 0.0], [-0.4, 29.5, 0.0], [1.9, 29.6, 0.0], [9.0, 30.0, 0.0],
                    [1.9, 29.6, 0.0], [1.8, 29.0, 0.0]])
    residual = np.array([-5.0, -5.1, -5.2, -5.0, 3.0, 0.0])
    moving = np.array([True, True, True, True, True, False])
    sep = separate(np.c_[pts, residual, np.full(6, 10.0)], moving, box[None], CAM, cfg)
    assert sep.owner.tolist() == [0, 0, -1, -1, -1, -1]
    owner = grow(pts, residual, moving, sep.owner, box[None], CAM, project(pts, CAM), cfg)
    assert owner.tolist() == [0, 0, 0, -1, -1, -1]
    # off: nothing changes
    off = grow(pts, residual, moving, sep.owner, box[None], CAM, project(pts, CAM), SeparationConfig(grow_eps_m=0.0))
    assert off.tolist() == sep.owner.tolist()
