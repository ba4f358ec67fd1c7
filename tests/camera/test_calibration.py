from pathlib import Path

import cv2
import numpy as np
import pytest

from mmatch.drivers.camera.calibration import (
    Calibration,
    EstimationError,
    dumps_calibration,
    estimate_T_cam_radar,
    load_calibration,
    project_radar,
    validate,
)
from mmatch.drivers.camera.errors import CalibrationError

EXAMPLE = Path(__file__).resolve().parents[2] / "cfg" / "camera" / "example_calibration.toml"
GOOD = EXAMPLE.read_text()


def _write(tmp_path, text):
    p = tmp_path / "calib.toml"
    p.write_text(text)
    return p


def test_example_file_loads_and_round_trips(tmp_path):
    c = load_calibration(EXAMPLE)
    assert c.image_size == (1280, 720) and c.K[0, 0] == 800.0 and c.dist.shape == (5,)
    assert c.ground.camera_height == 1.10 and c.ground.pitch_deg == 2.0
    from mmatch.drivers.camera.depth import GroundPlane

    derived = GroundPlane.from_extrinsic(c.T_cam_radar, radar_height=1.0)
    assert derived.pitch_deg == pytest.approx(
        2.0, abs=1e-6
    ) and derived.camera_height == pytest.approx(1.10, abs=1e-3)
    again = load_calibration(_write(tmp_path, dumps_calibration(c)))
    np.testing.assert_array_equal(again.K, c.K)
    np.testing.assert_array_equal(again.T_cam_radar, c.T_cam_radar)
    np.testing.assert_array_equal(again.dist, c.dist)
    assert again.ground == c.ground
    model = c.camera_model()
    assert model.image_size == (1280, 720) and model.K is not c.K


@pytest.mark.parametrize(
    "old,new,key,what",
    [
        ('format = "mmatch-camera-calibration/1"', 'format = "x"', "format", "expected"),
        ("image_size = [1280, 720]", "image_size = [1280]", "camera.image_size", "width, height"),
        ("[0.0, 800.0, 360.0]", "[0.0, 800.0]", "camera.K", "shape"),
        ("K = [[800.0,", "K = [[8.0,", "camera.K", "field of view"),
        ("[0.0, 800.0, 360.0]", "[0.0, 2000.0, 360.0]", "camera.K", "fx/fy"),
        ("[0.0, 800.0, 360.0]", "[0.0, 800.0, 900.0]", "camera.K", "principal point"),
        ("[0.0, 800.0, 360.0]", "[0.0, -800.0, 360.0]", "camera.K", "positive"),
        (
            "dist = [-0.12, 0.05, 0.0, 0.0, 0.0]",
            "dist = [-0.12, 0.05, 0.0]",
            "camera.dist",
            "coefficients",
        ),
        (
            "T_cam_radar = [[1.0, 0.0, 0.0, 0.0]",
            "T_cam_radar = [[1.1, 0.0, 0.0, 0.0]",
            "extrinsic.T_cam_radar",
            "orthonormal",
        ),
        (
            "T_cam_radar = [[1.0, 0.0, 0.0, 0.0]",
            "T_cam_radar = [[-1.0, 0.0, 0.0, 0.0]",
            "extrinsic.T_cam_radar",
            "reflection",
        ),
        ("[0.0, 0.0, 0.0, 1.0]]", "[0.0, 0.0, 1.0, 1.0]]", "extrinsic.T_cam_radar", "last row"),
        ("0.05346]", "55.0]", "extrinsic.T_cam_radar", "over 10 m"),
        ("camera_height = 1.10", "camera_height = 40.0", "ground.camera_height", "0.1..10"),
        ("pitch_deg = 2.0  ", "pitch_deg = 80.0  ", "ground.pitch_deg", "-45..45"),
        ("roll_deg = 0.0", "roll_deg = 0.0\nyaw_deg = 1.0", "ground.yaw_deg", "unknown key"),
        ("[extrinsic]", "[extrinsics]", "extrinsics", "unknown table"),
    ],
)
def test_errors_name_the_key(tmp_path, old, new, key, what):
    assert old in GOOD, old
    p = _write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(CalibrationError, match=what) as exc:
        load_calibration(p)
    assert exc.value.key == key
    assert str(p) in str(exc.value) and repr(key) in str(exc.value)


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(CalibrationError, match="no such file"):
        load_calibration(tmp_path / "none.toml")
    with pytest.raises(CalibrationError, match="not valid TOML"):
        load_calibration(_write(tmp_path, "K = [[1, 2"))
    with pytest.raises(CalibrationError) as exc:
        load_calibration(
            _write(
                tmp_path,
                GOOD.replace(
                    "K = [[800.0, 0.0, 640.0],\n     [0.0, 800.0, 360.0],\n     [0.0, 0.0, 1.0]]",
                    "",
                ),
            )
        )
    assert exc.value.key == "camera.K"
    with pytest.raises(CalibrationError) as exc:
        validate(np.eye(3) * 800, [], (640, 480), np.full((4, 4), np.nan))
    assert exc.value.key == "camera.K"  # K[2] != (0, 0, 1) is checked first
    with pytest.raises(CalibrationError, match="non-finite") as exc:
        validate([[500, 0, 320], [0, 500, 240], [0, 0, 1]], [], (640, 480), np.full((4, 4), np.nan))
    assert exc.value.key == "extrinsic.T_cam_radar"


def test_undistort_boxes_contains_the_undistorted_outline():
    c = load_calibration(EXAMPLE)
    rng = np.random.default_rng(0)
    distorted = np.array(
        [
            [100, 80, 300, 200, 0.9, 5],
            [900, 400, 1270, 710, 0.8, 7],
            [600, 300, 700, 380, 0.7, 9],
            [0, 0, 1280, 720, 0.5, 3],
        ],
        np.float32,
    )
    und = c.undistort_boxes(distorted)
    for box, got in zip(distorted, und, strict=True):
        # reference: undistort 400 points along the box outline
        t = np.linspace(0, 1, 100)
        u1, v1, u2, v2 = box[:4]
        outline = np.concatenate(
            [
                np.c_[u1 + (u2 - u1) * t, np.full(100, v1)],
                np.c_[u1 + (u2 - u1) * t, np.full(100, v2)],
                np.c_[np.full(100, u1), v1 + (v2 - v1) * t],
                np.c_[np.full(100, u2), v1 + (v2 - v1) * t],
            ]
        )
        ref = c.undistort_points(outline)
        np.testing.assert_allclose(got[:4], np.r_[ref.min(0), ref.max(0)], atol=0.05)
    np.testing.assert_array_equal(und[:, 4:], distorted[:, 4:])
    # undistort_points inverts OpenCV's distortion model
    ideal = rng.uniform([50, 50], [1230, 670], (50, 2))
    rays = np.c_[(ideal - c.K[:2, 2]) / np.diag(c.K)[:2], np.ones(50)]
    dist_px, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), c.K, c.dist)
    np.testing.assert_allclose(c.undistort_points(dist_px.reshape(-1, 2)), ideal, atol=1e-2)
    # barrel distortion (k1 < 0): undistorted boxes near the border grow outward
    assert und[3, 0] < 0 and und[3, 2] > 1280
    # no distortion: identity
    flat = Calibration(c.K, np.zeros(5), c.image_size, c.T_cam_radar)
    np.testing.assert_array_equal(flat.undistort_boxes(distorted), distorted)


def _pairs(c, n=40, seed=0, noise_px=1.0, outliers=4):
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(-12, 12, n), rng.uniform(6, 60, n), rng.uniform(-0.6, 0.8, n)]
    pc = pts @ c.T_cam_radar[:3, :3].T + c.T_cam_radar[:3, 3]
    uv, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), c.K, c.dist)
    uv = uv.reshape(-1, 2) + rng.normal(0, noise_px, (n, 2))
    uv[:outliers] += rng.uniform(40, 120, (outliers, 2))
    return pts, uv


@pytest.mark.parametrize("with_init", [True, False])
def test_estimate_T_cam_radar_from_pairs(with_init):
    c = load_calibration(EXAMPLE)
    pts, uv = _pairs(c)
    T_init = None
    if with_init:
        T_init = np.eye(4)
        T_init[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # nominal mounting, no pitch, no offset
    T, info = estimate_T_cam_radar(pts, uv, c.K, c.dist, T_init=T_init)
    dR = T[:3, :3].T @ c.T_cam_radar[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    assert angle < 0.3
    assert np.linalg.norm(T[:3, 3] - c.T_cam_radar[:3, 3]) < 0.15
    assert info["rms_px"] < 2.0
    assert set(range(4)).isdisjoint(info["inliers"].tolist())  # the 4 outliers were rejected
    assert len(info["inliers"]) >= 34
    # and the estimate reprojects the inliers where they were seen
    proj = project_radar(pts[info["inliers"]], c.K, T)
    assert np.isfinite(proj).all()


def test_estimate_needs_enough_pairs():
    c = load_calibration(EXAMPLE)
    pts, uv = _pairs(c, n=5, outliers=0)
    with pytest.raises(EstimationError, match="at least 6"):
        estimate_T_cam_radar(pts, uv, c.K)
    with pytest.raises(EstimationError, match="pixels"):
        estimate_T_cam_radar(pts, uv[:3], c.K)


def test_extrinsic_from_a_recording_with_a_rough_start():
    """Frames of vehicle centroids + boxes (with clutter: false boxes, vehicles without a box),
    a nominal mounting 2 deg and 15 cm off: pairing and estimation converge to the truth."""
    from mmatch.drivers.camera.calibration import collect_pairs, estimate_T_cam_radar_from_recording

    c = load_calibration(EXAMPLE)
    rng = np.random.default_rng(7)
    frames = []
    for _ in range(40):
        n = rng.integers(1, 5)
        pts = np.c_[rng.uniform(-12, 12, n), rng.uniform(8, 60, n), rng.uniform(-0.3, 0.6, n)]
        pc = pts @ c.T_cam_radar[:3, :3].T + c.T_cam_radar[:3, 3]
        uv, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), c.K, c.dist)
        uv = uv.reshape(-1, 2) + rng.normal(0, 2.0, (n, 2))
        half = np.c_[np.full(n, 40.0), np.full(n, 25.0)]
        boxes = np.c_[uv - half, uv + half]
        keep = rng.uniform(size=n) > 0.15  # some vehicles are not detected
        boxes = boxes[keep]
        if rng.uniform() < 0.3:  # a false detection
            fake = rng.uniform([0, 300], [1200, 650])
            boxes = np.r_[boxes, [[*fake, *(fake + 60)]]]
        frames.append((pts, boxes))
    rot = cv2.Rodrigues(np.deg2rad([1.0, 1.5, 0.5]))[0]
    T0 = c.T_cam_radar.copy()
    T0[:3, :3] = rot @ T0[:3, :3]
    T0[:3, 3] += (0.1, -0.1, 0.05)
    pts, px = collect_pairs(frames, c.K, T0, c.dist)
    assert len(pts) >= 20

    def angle_to_truth(T):
        dR = T[:3, :3].T @ c.T_cam_radar[:3, :3]
        return np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))

    assert angle_to_truth(T0) > 1.5  # the start is really off
    T, info = estimate_T_cam_radar_from_recording(frames, c.K, T0, c.dist)
    assert angle_to_truth(T) < 0.3
    assert np.linalg.norm(T[:3, 3] - c.T_cam_radar[:3, 3]) < 0.2
    assert info["pairs"] >= 40 and info["rms_px"] < 4.0
