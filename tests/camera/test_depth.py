import numpy as np
import pytest

from mmatch.drivers.camera.depth import DepthConfig, GroundPlane, ground_plane_depth, model_depth_sigma

K = np.array([[800.0, 0, 640], [0, 800.0, 360], [0, 0, 1]])


def _project_ground(X, Z, h, pitch_deg):
    """Pixel of the road point (X lateral, Z forward along the road) for a camera h above the
    road, pitched down by pitch_deg."""
    p = np.deg2rad(pitch_deg)
    # level frame (x right, y down, z forward along the road) -> camera pitched down: Rx(+p)
    R = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    pc = R @ np.array([X, h, Z])
    uvw = K @ pc
    return uvw[:2] / uvw[2]


@pytest.mark.parametrize("pitch", [0.0, 3.0, -2.0])
@pytest.mark.parametrize("X,Z", [(0.0, 8.0), (-3.5, 20.0), (4.0, 45.0)])
def test_ground_plane_recovers_distance(pitch, X, Z):
    h = 1.4
    u, v = _project_ground(X, Z, h, pitch)
    box = np.array([[u - 40, v - 60, u + 40, v]])
    cfg = DepthConfig(center_offset=0.0, vehicle_height=0.0)
    d, s = ground_plane_depth(box, K, GroundPlane(h, pitch), config=cfg)
    assert d[0] == pytest.approx(np.sqrt(X**2 + h**2 + Z**2), rel=1e-4)
    # the uncertainty grows with distance (pixel error matters more far away)
    assert s[0] > 1.0


def test_uncertainty_grows_with_range_and_center_offset_adds():
    g = GroundPlane(1.5, 0.0)
    rows = 360 + 800 * 1.5 / np.array([5.0, 10.0, 20.0, 40.0])
    boxes = np.stack([np.full(4, 600), rows - 50, np.full(4, 680), rows], 1)
    d0, s0 = ground_plane_depth(
        boxes, K, g, config=DepthConfig(center_offset=0.0, vehicle_height=0.0)
    )
    d1, s1 = ground_plane_depth(boxes, K, g)
    np.testing.assert_allclose(d0, np.hypot([5.0, 10.0, 20.0, 40.0], 1.5), rtol=1e-4)
    assert np.all(np.diff(s0) > 0)
    assert np.all(d1 > d0) and np.all(d1 < d0 + 1.6)
    # 40 m with 2 px and 1 deg: the pitch term dominates, several metres
    assert 5 < s0[-1] < 40


def test_above_horizon_falls_back_to_size_prior():
    g = GroundPlane(1.5, 0.0)
    box = np.array(
        [[600, 300, 700, 350.0], [600, 100, 700, 360.0]]
    )  # bottom above / at the horizon
    d, s = ground_plane_depth(box, K, g)
    cfg = DepthConfig()
    np.testing.assert_allclose(d, 800 * cfg.vehicle_height / np.array([50.0, 260.0]), rtol=1e-5)
    np.testing.assert_allclose(s, d * cfg.size_prior_rel_sigma, rtol=1e-5)


def test_cut_off_box_gets_double_sigma_and_empty_input():
    g = GroundPlane(1.5, 0.0)
    box = np.array([[600, 500, 700, 719.0]])
    _, s_free = ground_plane_depth(box, K, g)
    _, s_cut = ground_plane_depth(box, K, g, image_size=(1280, 720))
    assert s_cut[0] == pytest.approx(2 * s_free[0])
    d, s = ground_plane_depth(np.zeros((0, 6)), K, g)
    assert d.shape == (0,) and s.shape == (0,)


def test_from_extrinsic_matches_explicit_plane():
    th = np.deg2rad(4.0)
    R0 = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])  # radar (x r, y fwd, z up) -> camera
    Rx = np.array([[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]])
    R = Rx @ R0
    cam_in_radar = np.array([0.1, -0.2, 0.35])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ cam_in_radar
    g = GroundPlane.from_extrinsic(T, radar_height=0.8)
    assert g.camera_height == pytest.approx(1.15)
    assert g.pitch_deg == pytest.approx(4.0)
    assert g.roll_deg == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(g.up(), R[:, 2], atol=1e-12)
    rolled = GroundPlane(1.0, 2.0, 5.0)
    back = rolled.up()
    assert np.degrees(np.arctan2(back[0], -back[1])) == pytest.approx(5.0)


def test_model_depth_sigma():
    np.testing.assert_allclose(model_depth_sigma(np.array([10.0, 30.0])), [1.0, 3.0])
