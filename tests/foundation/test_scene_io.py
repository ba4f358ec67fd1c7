"""mmatch-scene/1 and mmatch-radar/1 readers: exact round trip, and every broken key named."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.errors import SceneFormatError
from mmatch.scene_io import load_radar_frame, load_scene, save_radar_frame, save_scene, scene_arrays
from mmatch.sim.scenario import make_scene


@pytest.fixture(scope="module")
def scene():
    return make_scene(seed=3, index=0, mode="hard")


def _write(path, arrays):
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)


def test_round_trip_is_exact(tmp_path, scene):
    save_scene(tmp_path / "a.npz", scene)
    back = load_scene(tmp_path / "a.npz")
    for key, value in scene_arrays(scene).items():
        assert np.array_equal(scene_arrays(back)[key], value), key
    assert back.meta == scene.meta
    assert back.name == "a"


@pytest.mark.parametrize("key, value, words", [
    ("ego_points", None, "missing"),
    ("cav_boxes", np.zeros((3, 5), np.float32), "shape"),
    ("ego_features", np.zeros((2, 32), np.float32), "rows"),
    ("gt_T_ego_cav", np.full((4, 4), np.nan), "NaN"),
    ("cav_K", np.eye(3, dtype=np.int32), "dtype"),
    ("ego_image_size", np.array([0, 720], np.int32), "non-positive"),
    ("gt_pairs", np.array([[99, 0]], np.int32), "out of range"),
    ("format", np.array("mmatch-scene/0"), "is not"),
    ("meta", np.array("{not json"), "JSON"),
    ("ego_K", np.diag([0.0, 900.0, 1.0]), "focal lengths"),                    # read before: "no vehicles"
    ("cav_K", np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 2]]), "last row"),
    ("ego_K", np.diag([9.0, 9.0, 1.0]), "field of view"),                        # focal in mm, not px
    ("cav_T_cam_radar", np.diag([2.0, 2.0, 2.0, 1.0]), "orthonormal"),          # a scaled rotation
    ("ego_T_cam_radar", np.diag([1.0, -1.0, 1.0, 1.0]), "det -1"),              # a mirrored axis
    ("gt_T_ego_cav", np.vstack([np.eye(4)[:3], [0.0, 0.0, 1.0, 1.0]]), "last row"),
])
def test_broken_key_is_named(tmp_path, scene, key, value, words):
    arrays = scene_arrays(scene)
    if value is None:
        del arrays[key]
    else:
        arrays[key] = value
    _write(tmp_path / "bad.npz", arrays)
    with pytest.raises(SceneFormatError) as err:
        load_scene(tmp_path / "bad.npz")
    assert err.value.key == key
    assert "bad.npz" in str(err.value) and words in str(err.value)


def test_not_an_npz_is_named(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"this is not a zip file")
    with pytest.raises(SceneFormatError, match="junk.npz"):
        load_scene(tmp_path / "junk.npz")


def test_radar_frame_round_trip_and_errors(tmp_path):
    pts = np.random.default_rng(0).normal(size=(7, 5)).astype(np.float32)
    save_radar_frame(tmp_path / "r.npz", pts, np.array([0.5, 12.0]), pts[:, 3] > 0)
    back = load_radar_frame(tmp_path / "r.npz")
    assert np.array_equal(back["points"], pts)
    assert np.array_equal(back["gt_moving"], pts[:, 3] > 0)
    _write(tmp_path / "r2.npz", {"format": np.array("mmatch-radar/1"), "points": pts,
                                 "gt_moving": np.ones(3, bool)})
    with pytest.raises(SceneFormatError, match="gt_moving"):
        load_radar_frame(tmp_path / "r2.npz")
