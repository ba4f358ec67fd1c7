import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from mmatch.drivers.camera.__main__ import main
from mmatch.drivers.camera.calibration import dumps_calibration, load_calibration, validate

from . import onnx_builder as ob
from .camera_synth import painted_scene


def test_check_model_and_detect(tmp_path, capsys):
    img, boxes, _ = painted_scene()
    out = np.zeros((1, 6, 100), np.float32)
    out[0, :4, 0] = (320, 320, 100, 50)
    out[0, 4, 0] = 0.9
    model = tmp_path / "det.onnx"
    model.write_bytes(ob.constant_model({"output0": out}, (1, 3, 640, 640)))
    calib = tmp_path / "c.toml"
    calib.write_text(
        dumps_calibration(
            validate(
                [[800, 0, 640], [0, 800, 360], [0, 0, 1]],
                [],
                (1280, 720),
                np.eye(4),
                {"camera_height": 1.4},
            )
        )
    )
    cv2.imwrite(str(tmp_path / "a.png"), img)
    assert main(["check-model", str(model)]) == 0
    assert "kind yolov8, input 640x640, 2 classes" in capsys.readouterr().out
    assert (
        main(
            ["detect", str(model), str(calib), str(tmp_path / "a.png"), str(tmp_path / "none.png")]
        )
        == 0
    )
    lines = capsys.readouterr().out.strip().splitlines()
    rec = json.loads(lines[0])
    assert (
        len(rec["boxes"]) == 1
        and rec["boxes"][0]["u1"] == 540.0
        and rec["boxes"][0]["score"] == 0.9
    )
    assert "skipped" in lines[1]
    assert main(["check-model", str(tmp_path / "none.onnx")]) == 2
    assert "none.onnx" in capsys.readouterr().err


def test_extrinsic_tool(tmp_path, capsys):
    src = load_calibration(
        Path(__file__).resolve().parents[2] / "cfg/camera/example_calibration.toml"
    )
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-10, 10, 30), rng.uniform(6, 50, 30), rng.uniform(-0.5, 0.5, 30)]
    pc = pts @ src.T_cam_radar[:3, :3].T + src.T_cam_radar[:3, 3]
    uv, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), src.K, src.dist)
    np.savetxt(
        tmp_path / "pairs.csv", np.c_[pts, uv.reshape(-1, 2)], delimiter=",", header="x,y,z,u,v"
    )
    start = tmp_path / "start.toml"
    T0 = np.eye(4)
    T0[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    start.write_text(dumps_calibration(dataclasses.replace(src, T_cam_radar=T0)))
    assert (
        main(
            [
                "extrinsic",
                str(tmp_path / "pairs.csv"),
                str(start),
                "--out",
                str(tmp_path / "o.toml"),
                "--init",
            ]
        )
        == 0
    )
    assert "30/30 pairs" in capsys.readouterr().out
    np.testing.assert_allclose(
        load_calibration(tmp_path / "o.toml").T_cam_radar, src.T_cam_radar, atol=1e-3
    )
