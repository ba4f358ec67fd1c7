"""Camera tools: `python -m mmatch.drivers.camera COMMAND ...` (a program: it prints; the library logs).

check-model MODEL [--kind K] [--input-size W H]
    load an ONNX detector and check its layout
detect MODEL CALIB IMAGE... [--kind K]
    run the detector stage on images, print the boxes as JSON lines
quantize SRC DST [--images IMG...]
    INT8 (dynamic, or static QDQ calibrated on images); needs the onnx package
extrinsic PAIRS.csv CALIB --out OUT [--init]
    estimate T_cam_radar from matched pairs (CSV columns x, y, z, u, v; radar m, image px)
oak-calibration --size W H --out OUT [--extrinsic-from CALIB] [--device ID]
    write the OAK's factory intrinsics as a calibration file
oak-check MODEL [CALIB]
    validate an NN archive / blob, then try to open the OAK
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from mmatch.errors import MMatchError


def _detector_config(model: str, kind: str | None, input_size: list[int] | None):
    from mmatch.drivers.camera.detector import DetectorConfig
    from mmatch.drivers.camera.sources import _sidecar

    settings = _sidecar(model)
    settings["model"] = model
    if kind:
        settings["kind"] = kind
    if input_size:
        settings["input_size"] = input_size
    return DetectorConfig.from_dict(settings)


def _check_model(a) -> int:
    from mmatch.drivers.camera.detector import OnnxDetector

    det = OnnxDetector(_detector_config(a.model, a.kind, a.input_size))
    print(
        f"{a.model}: ok: kind {det.config.kind}, input {det.input_size[0]}x{det.input_size[1]}, "
        f"{det.num_classes} classes"
    )
    return 0


def _detect(a) -> int:
    import cv2

    from mmatch.drivers.camera.calibration import load_calibration
    from mmatch.drivers.camera.detector import OnnxDetector
    from mmatch.drivers.camera.pipeline import DetectionStage

    det = OnnxDetector(_detector_config(a.model, a.kind, a.input_size))
    stage = DetectionStage(det.detect, load_calibration(a.calibration), radar_height=a.radar_height)
    for path in a.images:
        img = cv2.imread(path, cv2.IMREAD_COLOR)
        out = stage.process(img, 0.0) if img is not None else None
        if out is None:
            print(f"{path}: skipped (unreadable or not the calibrated size)")
            continue
        names = ("u1", "v1", "u2", "v2", "score", "depth")
        rows = [
            {
                **{k: round(float(x), 3) for k, x in zip(names, b, strict=True)},
                "depth_sigma": round(float(s), 3),
                "cls": int(c),
            }
            for b, s, c in zip(out.boxes, out.depth_sigma, out.classes, strict=True)
        ]
        print(json.dumps({"image": path, "boxes": rows}))
    return 0


def _quantize(a) -> int:
    import cv2

    from mmatch.drivers.camera.quantize import quantize_detector

    images = [cv2.imread(p, cv2.IMREAD_COLOR) for p in a.images] if a.images else None
    cfg = _detector_config(a.src, a.kind, a.input_size) if images else None
    print(quantize_detector(a.src, a.dst, calibration_images=images, detector_config=cfg))
    return 0


def _extrinsic(a) -> int:
    import dataclasses

    from mmatch.drivers.camera.calibration import estimate_T_cam_radar, load_calibration, save_calibration

    calib = load_calibration(a.calibration)
    data = np.loadtxt(a.pairs, delimiter=",", comments="#", ndmin=2)
    if data.shape[1] < 5:
        raise MMatchError(f"{a.pairs}: expected columns x, y, z, u, v")
    T, info = estimate_T_cam_radar(
        data[:, :3],
        data[:, 3:5],
        calib.K,
        calib.dist,
        T_init=calib.T_cam_radar if a.init else None,
        reprojection_px=a.px,
    )
    save_calibration(a.out, dataclasses.replace(calib, T_cam_radar=T))
    print(
        f"{a.out}: T_cam_radar from {len(info['inliers'])}/{info['n']} pairs, "
        f"rms {info['rms_px']:.2f} px"
    )
    return 0


def _oak_calibration(a) -> int:
    from mmatch.drivers.camera.calibration import load_calibration, save_calibration
    from mmatch.drivers.camera.sources.oak import calibration_from_oak, import_depthai

    dai = import_depthai()
    T = (
        load_calibration(a.extrinsic_from).T_cam_radar
        if a.extrinsic_from
        else np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    )
    try:
        device = dai.Device(dai.DeviceInfo(a.device)) if a.device else dai.Device()
    except RuntimeError as exc:
        raise MMatchError(f"no OAK device found: {exc}") from exc
    with device:
        calib = calibration_from_oak(device.readCalibration(), tuple(a.size), T, dai=dai)
    save_calibration(a.out, calib)
    print(
        f"{a.out}: factory intrinsics of CAM_A at {a.size[0]}x{a.size[1]}"
        + (
            ""
            if a.extrinsic_from
            else "; T_cam_radar is the nominal axis swap: estimate it (extrinsic)"
        )
    )
    return 0


def _oak_check(a) -> int:
    from mmatch.drivers.camera.calibration import load_calibration, validate
    from mmatch.drivers.camera.sources import _sidecar
    from mmatch.drivers.camera.sources.oak import OakCamera, OakConfig

    settings = _sidecar(a.model)
    settings["model"] = a.model
    calib = (
        load_calibration(a.calibration)
        if a.calibration
        else validate([[800, 0, 640], [0, 800, 360], [0, 0, 1]], [], (1280, 720), np.eye(4))
    )
    cam = OakCamera(OakConfig(**settings), calib)
    print(f"{a.model}: ok ({cam.model.kind}, NN input {cam.model.input_size})")
    with cam:
        det = cam.read(5.0)
        print(
            "OAK running: "
            + ("no detections within 5 s" if det is None else f"{len(det.boxes)} boxes")
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m mmatch.drivers.camera",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("check-model")
    s.add_argument("model")
    s.add_argument("--kind")
    s.add_argument("--input-size", nargs=2, type=int)
    s.set_defaults(fn=_check_model)
    s = sub.add_parser("detect")
    s.add_argument("model")
    s.add_argument("calibration")
    s.add_argument("images", nargs="+")
    s.add_argument("--kind")
    s.add_argument("--input-size", nargs=2, type=int)
    s.add_argument("--radar-height", type=float)
    s.set_defaults(fn=_detect)
    s = sub.add_parser("quantize")
    s.add_argument("src")
    s.add_argument("dst")
    s.add_argument("--images", nargs="*")
    s.add_argument("--kind")
    s.add_argument("--input-size", nargs=2, type=int)
    s.set_defaults(fn=_quantize)
    s = sub.add_parser("extrinsic")
    s.add_argument("pairs")
    s.add_argument("calibration")
    s.add_argument("--out", required=True)
    s.add_argument("--init", action="store_true", help="start from the calibration's T_cam_radar")
    s.add_argument("--px", type=float, default=8.0, help="RANSAC inlier threshold, px")
    s.set_defaults(fn=_extrinsic)
    s = sub.add_parser("oak-calibration")
    s.add_argument("--size", nargs=2, type=int, required=True)
    s.add_argument("--out", required=True)
    s.add_argument("--extrinsic-from")
    s.add_argument("--device", default="")
    s.set_defaults(fn=_oak_calibration)
    s = sub.add_parser("oak-check")
    s.add_argument("model")
    s.add_argument("calibration", nargs="?")
    s.set_defaults(fn=_oak_check)
    a = p.parse_args(argv)
    try:
        return a.fn(a)
    except MMatchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
