"""`mmatch dsp` on a synthesised capture, its errors, and the bench suite smoke run."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from mmatch.drivers.dca1000.bench import AWR2243_BENCH_CFG
from mmatch.drivers.dca1000.layout import FrameGeometry
from mmatch.drivers.dca1000.synth import Target, synth_raw_frames
from mmatch.drivers.ti.cfg import parse_cfg
from mmatch.edge.cli import main

CFG_PATH = Path(__file__).parent / "awr2243_3tx.cfg"


@pytest.fixture(autouse=True)
def _quiet_cfg_warnings():
    logging.getLogger("mmatch.drivers.ti.cfg").setLevel(logging.ERROR)


def test_dsp_command_writes_points_per_frame(tmp_path, radar_cfg, capsys):
    geom = FrameGeometry.from_chirp(radar_cfg.chirp)
    targets = [Target(18.0, 5.0, 25.0, 0.0), Target(40.0, -8.0, -15.0, 0.0)]
    cap = tmp_path / "adc_data_Raw_0.bin"
    cap.write_bytes(synth_raw_frames(radar_cfg.chirp, geom, targets, 3, seed=4))
    out = tmp_path / "points.json"
    assert main(["dsp", "--cfg", str(CFG_PATH), "--adc", str(cap), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc) == {"frames", "points_per_frame", "points"}
    assert doc["frames"] == 3 and doc["points_per_frame"] == [2, 2, 2]
    for frame in doc["points"]:
        pts = np.asarray(frame)
        assert pts.shape == (2, 5)
        right = pts[np.argmax(pts[:, 0])]
        assert right[0] > 0 and right[3] > 0  # the receding target on the right
        assert abs(np.linalg.norm(right[:3]) - 18.0) < 1.0
    assert "3 frames" in capsys.readouterr().out


def test_dsp_command_refuses_a_capture_that_does_not_match(tmp_path, radar_cfg, capsys):
    geom = FrameGeometry.from_chirp(radar_cfg.chirp)
    cap = tmp_path / "bad.bin"
    cap.write_bytes(b"\x01" * (geom.frame_bytes + 5000))
    assert main(["dsp", "--cfg", str(CFG_PATH), "--adc", str(cap)]) == 2
    err = capsys.readouterr().err
    assert "not a whole number" in err and "1 frames + 5000 bytes" in err


def test_bench_cfg_is_the_shipped_test_cfg(radar_cfg):
    assert parse_cfg(AWR2243_BENCH_CFG, "<bench>").chirp == radar_cfg.chirp


def test_bench_quick_smoke():
    from mmatch.drivers.dca1000.bench import run

    out = run(quick=True)
    assert all(isinstance(v, (int, float)) for v in out.values())
    assert out["dsp_frame_ms_median"] > 0 and out["dsp_points"] == out["dsp_targets"]
    assert (
        out["dsp_doppler_bins"] == 128
        and out["dsp_virtual_channels"] == 12
        and out["dsp_samples"] == 256
    )
    # speed and completeness at line rate are the bench's to report (the kernel may drop on a
    # starved machine); here: frames arrived, and every frame is exact or flagged, never wrong
    assert out["loopback_frames_sent"] == 8 and out["loopback_frames"] >= 6
    assert out["loopback_frames_exact"] + out["loopback_frames_flagged"] == out["loopback_frames"]
    assert out["loopback_mb_per_s"] > 0


def test_dsp_command_options(tmp_path, radar_cfg):
    geom = FrameGeometry.from_chirp(radar_cfg.chirp)
    cap = tmp_path / "c_Raw_0.bin"
    cap.write_bytes(synth_raw_frames(radar_cfg.chirp, geom, [Target(25.0, 0.0, -30.0)], 4))
    out = tmp_path / "p.json"
    argv = ["dsp", "--cfg", str(CFG_PATH), "--adc", str(cap), "--json", str(out)]
    assert main([*argv, "--max-frames", "2", "--cfar", "os"]) == 0
    doc = json.loads(out.read_text())
    assert doc["frames"] == 2 and doc["points_per_frame"] == [1, 1]
    assert doc["points"][0][0][0] < 0  # left
    assert main([*argv, "--clutter-removal", "on"]) == 0  # a static target disappears
    assert json.loads(out.read_text())["points_per_frame"] == [0, 0, 0, 0]
    assert main([*argv, "--mirror-x"]) == 0  # the same capture read as a mirrored board
    assert json.loads(out.read_text())["points"][0][0][0] > 0
    assert main([*argv, "--average", "ca"]) == 0  # whole-ring CA instead of the cfg's CASO
    assert json.loads(out.read_text())["points_per_frame"] == [1, 1, 1, 1]


def test_dsp_angle_study_prints_the_tables(capsys):
    assert main(["dsp", "--angle-study", "--frames", "2", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert out.count("per band of reported SNR") == 2 and out.count("per |azimuth|") == 2
    for band in ("5-10", "10-15", "15-20", "20-30", "30-45", ">45"):
        assert f"{band:>9} " in out
    assert "vehicles" in out and "point targets" in out and "2 frames per kind, seed 3" in out


def test_dsp_command_needs_a_capture_or_the_study(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["dsp", "--cfg", str(CFG_PATH)])
    assert exc.value.code == 2 and "--adc are required" in capsys.readouterr().err
    assert main(["dsp", "--angle-study", "--frames", "0"]) == 2
