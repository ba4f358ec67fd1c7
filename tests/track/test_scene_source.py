"""Scene files as the sensors of `mmatch run`: one side of a drive, its stamps kept, on its own clock."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mmatch.edge import config
from mmatch.edge.sources import open_camera, open_radar
from mmatch.edge.sources.base import EndOfStream
from mmatch.edge.sources.replay import RECORDED_DETECTIONS
from mmatch.errors import ConfigError
from mmatch.scene_io import load_scene


def _cfg(folder, role="ego", **scene):
    return config.from_dict({"vehicle": {"id": "v1", "role": role}, "radar": {"source": "scene"},
                             "camera": {"source": "scene"}, "scene": {"path": str(folder), **scene}})


def test_plays_one_side_of_a_drive_with_its_stamps_and_detections(short_sequences):
    folder, _ = short_sequences
    files = sorted(folder.glob("*.npz"))
    first_seq = sorted({load_scene(str(f)).meta["sequence"] for f in files})[0]
    for role, side in (("ego", "ego"), ("cav", "cav")):
        radar = open_radar(_cfg(folder, role, start=time.time() - 100.0))      # long due: no waiting
        camera = open_camera(_cfg(folder, role), radar=radar)
        scenes = [load_scene(f) for f in radar.files]
        assert len(scenes) == 12 and {s.meta["sequence"] for s in scenes} == {first_seq}
        assert [s.meta["frame"] for s in scenes] == list(range(12))
        v0 = getattr(scenes[0], side)
        np.testing.assert_array_equal(camera.camera.K, v0.camera.K)
        assert radar.radar_height == v0.radar_height
        assert radar.clock() == pytest.approx(scenes[0].ego.stamp + 100.0, abs=1.0)
        for s in scenes:
            f = radar.read(1.0)
            v = getattr(s, side)
            assert f.stamp == v.stamp                                               # exactly the file's
            np.testing.assert_array_equal(f.points, v.points)
            det = f.device[RECORDED_DETECTIONS]
            np.testing.assert_array_equal(det.boxes, v.boxes)
            np.testing.assert_array_equal(det.features, v.features)
        with pytest.raises(EndOfStream):
            radar.read(1.0)
        camera.close()
        camera.close()


def test_frames_are_due_on_the_drive_clock_less_the_lead(short_sequences):
    folder, _ = short_sequences
    radar = open_radar(_cfg(folder, start=time.time() + 30.0, lead_s=0.5))
    t0 = time.monotonic()
    assert radar.read(0.2) is None and time.monotonic() - t0 >= 0.15             # not due for 30 s
    radar = open_radar(_cfg(folder, start=time.time() + 0.3, lead_s=0.25))
    f = radar.read(2.0)
    assert f is not None and radar.clock() == pytest.approx(f.stamp - 0.25, abs=0.1)


def test_what_cannot_be_played_names_the_key(short_sequences, tmp_path):
    folder, _ = short_sequences
    with pytest.raises(ConfigError, match="scene.path"):
        config.from_dict({"vehicle": {"id": "v1", "role": "ego"}, "radar": {"source": "scene"}})
    with pytest.raises(ConfigError, match="camera.source"):
        config.from_dict({"vehicle": {"id": "v1", "role": "ego"}, "camera": {"source": "scene"}})
    with pytest.raises(ConfigError, match="scene.sequence.*nope"):
        open_radar(_cfg(folder, sequence="nope"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="scene.path.*no drive"):
        open_radar(_cfg(tmp_path / "empty"))
    with pytest.raises(ConfigError, match="scene.path.*not a folder"):
        open_radar(_cfg(tmp_path / "missing"))
    assert config.auth_mode(_cfg(folder)) == "dev"                               # simulated data: dev keys
