"""Physics as a family: documented ranges, drawn per scene, bad ranges refused naming the key."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.errors import ConfigError
from mmatch.evaluate import EvalConfig, evaluate_scene
from mmatch.sim.physics import KNOBS, PhysicsSample, family
from mmatch.sim.scenario import make_scene


def test_nominal_is_one_point_and_wide_draws_inside_its_ranges():
    nom = family("nominal")
    assert all(lo == hi == KNOBS[k].nominal for k, (lo, hi) in nom.ranges.items())
    wide = family("wide")
    draws = [wide.draw(np.random.default_rng(s)) for s in range(30)]
    for key, (lo, hi) in wide.ranges.items():
        vals = np.array([getattr(d, key) for d in draws])
        assert np.all(vals >= lo - 1e-9) and np.all(vals <= hi + 1e-9), key
        if hi > lo and not KNOBS[key].integer:
            assert np.ptp(vals) > 0.3 * (hi - lo), key        # really drawn, not fixed
    assert set(KNOBS) == {f for f in PhysicsSample.__dataclass_fields__}


@pytest.mark.parametrize("text, key", [
    ("range_sigma_m = -0.1", "range_sigma_m"),                       # negative noise
    ("ghost_prob = [0.1, 1.5]", "ghost_prob"),                       # a probability above 1
    ("miss_prob = [0.2, 0.1]", "miss_prob"),                         # an empty range
    ("clutter_rate = 'lots'", "clutter_rate"),                       # not a number
    ("angle_noise = 2.0", "angle_noise"),                            # unknown key
])
def test_bad_physics_files_are_refused_naming_the_key(tmp_path, text, key):
    f = tmp_path / "physics.toml"
    f.write_text(text + "\n")
    with pytest.raises(ConfigError, match=f"physics.{key}"):
        family(f)


def test_a_physics_file_narrows_the_wide_family(tmp_path):
    f = tmp_path / "physics.toml"
    f.write_text("[physics]\nfalse_detection_rate = [0.9, 1.0]\nangle_noise_scale = 1.2\n")
    fam = family(f)
    assert fam.ranges["false_detection_rate"] == (0.9, 1.0) and fam.ranges["angle_noise_scale"] == (1.2, 1.2)
    assert fam.ranges["ghost_prob"] == KNOBS["ghost_prob"].wide


def test_scenes_record_their_physics_and_a_scene_without_covisible_vehicles_is_valid():
    scenes = [make_scene(5, i, "hard", "wide") for i in range(40)]
    for s in scenes:
        vals = s.meta["physics_values"]
        assert s.meta["physics"] == "wide" and set(vals) == set(KNOBS)
    few = [s for s in scenes if len(s.gt_pairs) < 2]
    assert 1 <= len(few) <= 12                                   # about 10 % of the scenes
    res = evaluate_scene(few[0], EvalConfig())
    assert "rejected" not in res and res["gt_pairs"] == len(few[0].gt_pairs)


def test_the_shipped_families_beyond_wide_load_and_stress_lies_inside_the_training_family():
    from pathlib import Path
    root = Path(__file__).resolve().parents[2] / "cfg" / "physics"
    wide, wider, stress = family("wide"), family(root / "wider.toml"), family(root / "stress.toml")
    widened = 0
    for key, (lo, hi) in wider.ranges.items():
        w_lo, w_hi = wide.ranges[key]
        s_lo, s_hi = stress.ranges[key]
        assert lo <= w_lo and hi >= w_hi, key                    # the training family covers wide
        assert lo <= s_lo and hi >= s_hi, key                    # and the stress family
        widened += (lo, hi) != (w_lo, w_hi)
    assert widened == 8


def test_camera_families_change_the_field_of_view_and_wide_keeps_ours():
    """`camera_focal_scale` scales each camera's focal length: the wide-angle family's cameras
    see 40-52 deg either side of their axis, the narrow family's 19-27, ours 30-35 (K in the
    scene files; the CAV side and the Ego read each camera's own)."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[2] / "cfg" / "physics"

    def half_fov_deg(scene) -> list[float]:
        return [float(np.degrees(np.arctan(v.camera.image_size[0] / 2 / v.camera.K[0, 0]))) for v in (scene.ego, scene.cav)]

    ours = [a for i in range(3) for a in half_fov_deg(make_scene(7, i, "hard", "wide"))]
    wide_angle = [a for i in range(3) for a in half_fov_deg(make_scene(7, i, "hard", root / "cameras-wide-angle.toml"))]
    narrow = [a for i in range(3) for a in half_fov_deg(make_scene(7, i, "hard", root / "cameras-narrow.toml"))]
    assert 30 <= min(ours) and max(ours) <= 35.5
    assert 40 <= min(wide_angle) and max(wide_angle) <= 52.5
    assert 18.5 <= min(narrow) and max(narrow) <= 27.5
    assert family("wide").ranges["camera_focal_scale"] == (1.0, 1.0)   # our camera: no draw, scenes as before
