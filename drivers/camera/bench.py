"""`mmatch bench` suite "camera": descriptor + decoding time per frame for 20 vehicle boxes.

One core (OpenCV threads = 1; numpy here is single-threaded), a 1280x720 frame with painted
vehicles, raw network outputs of realistic size with 20 true boxes, a weaker duplicate of
each (for NMS) and low-score noise:
- yolov8: (1, 84, 8400) (640x640 input, 80 classes); yolov5: (1, 25200, 85);
- centernet: heatmap (1, 80, 128, 128) + wh/reg (512x512 input, stride 4).
Reports median, p90 and min in ms (and the 1-minute load average, since the machine may be
shared). The issue's 2 ms target is `descriptor_plus_decode_v8_ms` (YOLOv8 decode + NMS + 20
descriptors as the driver computes them, boxes sampled to <= 4096 pixels);
`descriptor_exact_plus_decode_v8_ms` uses every box pixel; `frame_v8_ms` is the driver's whole
per-frame host work after inference (decode, NMS, descriptors, undistortion, depth).
"""

from __future__ import annotations

import os
import time

import numpy as np

N_BOXES = 20


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    W, H = 1280, 720
    img = np.empty((H, W, 3), np.uint8)
    img[: H // 3] = (230, 200, 160)
    img[H // 3 :] = (105, 105, 105)
    img = np.clip(img.astype(np.int16) + rng.integers(-8, 9, img.shape), 0, 255).astype(np.uint8)
    # a 5 x 4 grid of cells over the road (no two boxes overlap), one vehicle per cell,
    # 40..240 px wide: about 300 k box pixels in all
    cols, rows = 5, 4
    cw, ch = W / cols, (H - 216) / rows
    w = rng.uniform(40, 240, N_BOXES)
    h = np.minimum(w * rng.uniform(0.45, 0.8, N_BOXES), ch - 2)
    cell = np.arange(N_BOXES)
    x1 = (cell % cols) * cw + rng.uniform(0, 1, N_BOXES) * (cw - w)
    y1 = 216 + (cell // cols) * ch + rng.uniform(0, 1, N_BOXES) * (ch - h)
    boxes = np.stack([x1, y1, x1 + w, y1 + h], 1).astype(np.float32)
    for b in boxes.astype(int):
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        cv2.rectangle(img, (b[0], b[1]), (b[2], b[3]), colour, -1)
    return img, boxes


def _yolo_raw(rng: np.random.Generator, boxes640: np.ndarray, v5: bool) -> np.ndarray:
    n, nc = (25200, 80) if v5 else (8400, 80)
    fixed = 5 if v5 else 4
    a = np.zeros((n, fixed + nc), np.float32)
    a[:, :2] = rng.uniform(0, 640, (n, 2))
    a[:, 2:4] = rng.uniform(8, 64, (n, 2))
    a[:, fixed:] = rng.uniform(0, 0.02, (n, nc))
    if v5:
        a[:, 4] = rng.uniform(0, 0.05, n)
    idx = rng.choice(n, 2 * len(boxes640), replace=False)
    for k, b in enumerate(boxes640):
        for j, shift in enumerate((0.0, 3.0)):
            r = idx[2 * k + j]
            bb = b + shift
            a[r, :4] = ((bb[0] + bb[2]) / 2, (bb[1] + bb[3]) / 2, bb[2] - bb[0], bb[3] - bb[1])
            a[r, fixed + 2] = 0.9 - 0.2 * j
            if v5:
                a[r, 4] = 0.95
    return a[None] if v5 else np.ascontiguousarray(a.T)[None]


def _centernet_raw(rng: np.random.Generator, boxes512: np.ndarray) -> tuple[np.ndarray, ...]:
    hm = rng.uniform(-9, -4, (1, 80, 128, 128)).astype(np.float32)  # logits, all below threshold
    wh = np.zeros((1, 2, 128, 128), np.float32)
    reg = np.zeros((1, 2, 128, 128), np.float32)
    for b in boxes512 / 4:
        cx, cy = int((b[0] + b[2]) / 2), int((b[1] + b[3]) / 2)
        cx, cy = min(cx, 127), min(cy, 127)
        hm[0, 2, cy, cx] = 2.5
        wh[0, :, cy, cx] = (b[2] - b[0], b[3] - b[1])
    return hm, wh, reg


def _stats(samples: list[float]) -> tuple[float, float, float]:
    a = np.asarray(samples) * 1e3
    return (
        round(float(np.median(a)), 4),
        round(float(np.percentile(a, 90)), 4),
        round(float(a.min()), 4),
    )


def run(quick: bool = False) -> dict:
    """Time the camera hot paths; returns a flat dict of numbers (ms unless named otherwise)."""
    import cv2

    from mmatch.drivers.camera.calibration import validate
    from mmatch.drivers.camera.decode import decode_centernet, decode_yolov5, decode_yolov8, suppress
    from mmatch.drivers.camera.descriptor import hsv_descriptor
    from mmatch.drivers.camera.detector import Letterbox
    from mmatch.drivers.camera.pipeline import DEFAULT_DESCRIPTOR_MAX_PIXELS, DetectionStage

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        rng = np.random.default_rng(0)
        img, boxes = _scene(rng)
        lb = Letterbox(0.5, 0.5, 0.0, 140.0)  # 1280x720 letterboxed into 640x640
        boxes640 = boxes * 0.5 + np.array([0, 140, 0, 140], np.float32)
        v8 = _yolo_raw(rng, boxes640, v5=False)
        v5 = _yolo_raw(rng, boxes640, v5=True)
        cn = _centernet_raw(rng, boxes * 0.4 + np.array([0, 112, 0, 112], np.float32))
        calib = validate(
            [[800, 0, 640], [0, 800, 360], [0, 0, 1]],
            [-0.1, 0.02, 0, 0, 0],
            (1280, 720),
            np.eye(4),
            {"camera_height": 1.4, "pitch_deg": 1.0},
        )
        reps = 15 if quick else 300

        def decode_v8():
            d = suppress(decode_yolov8(v8, 0.25), 0.45)
            d.boxes = lb.to_image(d.boxes, 1280, 720)
            return d

        stage = DetectionStage(lambda image: decode_v8(), calib)
        cases = {
            "decode_v8": decode_v8,
            "decode_v5": lambda: suppress(decode_yolov5(v5, 0.25), 0.45),
            "decode_centernet": lambda: suppress(
                decode_centernet(*cn, stride=4.0, score_threshold=0.25), 0.45
            ),
            "descriptor_20": lambda: hsv_descriptor(
                img, boxes, max_pixels=DEFAULT_DESCRIPTOR_MAX_PIXELS
            ),
            "descriptor_20_exact": lambda: hsv_descriptor(img, boxes),
            "frame_v8": lambda: stage.process(img, 0.0),
        }
        out: dict[str, float] = {}
        found = len(decode_v8())
        for name, fn in cases.items():
            fn()  # warm-up
            samples = []
            for _ in range(reps):
                t0 = time.perf_counter()
                fn()
                samples.append(time.perf_counter() - t0)
            out[f"{name}_ms"], out[f"{name}_p90_ms"], out[f"{name}_min_ms"] = _stats(samples)
        out["descriptor_plus_decode_v8_ms"] = round(
            out["decode_v8_ms"] + out["descriptor_20_ms"], 4
        )
        out["descriptor_plus_decode_v8_min_ms"] = round(
            out["decode_v8_min_ms"] + out["descriptor_20_min_ms"], 4
        )
        out["descriptor_exact_plus_decode_v8_ms"] = round(
            out["decode_v8_ms"] + out["descriptor_20_exact_ms"], 4
        )
        out["descriptor_max_pixels"] = float(DEFAULT_DESCRIPTOR_MAX_PIXELS)
        out["loadavg_1min"] = round(
            os.getloadavg()[0], 2
        )  # the machine is shared: read the times with it
        out["boxes_found_v8"] = float(found)
        out["box_pixels"] = float(np.prod(np.diff(boxes.reshape(-1, 2, 2), axis=1), axis=-1).sum())
        out["target_ms"] = 2.0
        out["reps"] = float(reps)
        return out
    finally:
        cv2.setNumThreads(threads)
