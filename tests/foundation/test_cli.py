"""The command line: help is instant, sim and demo run on small inputs."""

from __future__ import annotations

import json
import subprocess
import sys
import time

from mmatch.edge.cli import main


def test_help_is_fast_and_lists_commands():
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "mmatch.edge.cli", "--help"], capture_output=True, text=True, check=True)
    assert time.monotonic() - t0 < 20
    for cmd in ("sim", "eval", "demo", "egomotion", "bench", "run", "replay", "parse-uart", "dsp"):
        assert cmd in out.stdout
    mods = subprocess.run([sys.executable, "-c", "import edge.cli, sys; edge.cli.build_parser();"
                           "print(','.join(m for m in ('cv2','onnxruntime','zenoh','depthai','sklearn') if m in sys.modules))"],
                          capture_output=True, text=True, check=True)
    assert mods.stdout.strip() == ""


def test_sim_writes_files_and_realism(tmp_path, capsys):
    assert main(["sim", "--out", str(tmp_path), "--n", "3", "--seed", "1", "--mode", "easy"]) == 0
    assert len(list(tmp_path.glob("*.npz"))) == 3
    fig = json.loads((tmp_path / "realism.json").read_text())
    assert fig["figures"]["scenes"] == 3
    assert "median_points_per_frame" in capsys.readouterr().out


def test_demo_writes_report_and_picture(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--n", "4", "--jobs", "1"]) == 0
    assert (tmp_path / "bev.png").stat().st_size > 1000
    assert json.loads((tmp_path / "eval.json").read_text())["scenes"] == 4
