"""Synthetic road images with painted vehicles (body, windows, wheels) for camera tests."""

from __future__ import annotations

import cv2
import numpy as np

# BGR body colours and the OpenCV hue (0..179) each has.
COLOURS = {
    "red": ((30, 30, 200), 0),
    "blue": ((200, 60, 30), 120),
    "green": ((40, 170, 40), 60),
    "yellow": ((20, 200, 220), 30),
}


def paint_vehicle(
    img: np.ndarray, box: tuple[int, int, int, int], colour_bgr: tuple[int, int, int]
) -> None:
    """Paint a side-view car inside box (x1, y1, x2, y2): body, cabin with windows, two wheels."""
    x1, y1, x2, y2 = box
    w, h = x2 - x1, y2 - y1
    body_top = y1 + int(0.40 * h)
    wheel_r = max(2, int(0.16 * h))
    body_bottom = y2 - wheel_r
    cv2.rectangle(img, (x1, body_top), (x2 - 1, body_bottom), colour_bgr, -1)
    cabin = (x1 + int(0.22 * w), y1, x2 - int(0.18 * w), body_top)
    cv2.rectangle(img, cabin[:2], (cabin[2] - 1, cabin[3]), colour_bgr, -1)
    m = max(1, int(0.06 * h))
    mid = (cabin[0] + cabin[2]) // 2
    cv2.rectangle(img, (cabin[0] + m, y1 + m), (mid - m, body_top - 1), (90, 80, 70), -1)  # windows
    cv2.rectangle(img, (mid + m, y1 + m), (cabin[2] - m, body_top - 1), (90, 80, 70), -1)
    for cx in (x1 + int(0.22 * w), x2 - int(0.22 * w)):
        cv2.circle(img, (cx, y2 - wheel_r), wheel_r, (20, 20, 20), -1)  # wheels


def road_image(width: int = 1280, height: int = 720, seed: int = 0) -> np.ndarray:
    """Sky, a grey road with lane marks, a little noise."""
    rng = np.random.default_rng(seed)
    img = np.empty((height, width, 3), np.uint8)
    img[: height // 3] = (230, 200, 160)  # sky (light blue)
    img[height // 3 :] = (105, 105, 105)  # asphalt
    for x in range(0, width, 160):
        cv2.rectangle(
            img, (x, int(height * 0.8)), (x + 70, int(height * 0.8) + 6), (240, 240, 240), -1
        )
    noise = rng.integers(-6, 7, img.shape)
    return np.clip(img.astype(np.int16) + noise, 0, 255).astype(np.uint8)


def painted_scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """A 1280x720 road with five painted vehicles: (image, boxes (5, 4) int, colour names)."""
    img = road_image(seed=seed)
    vehicles = [
        ((100, 330, 340, 450), "red"),
        ((420, 350, 600, 440), "blue"),
        ((660, 300, 960, 460), "green"),
        ((1000, 340, 1200, 440), "yellow"),
        ((1100, 500, 1279, 640), "red"),
    ]
    for box, name in vehicles:
        paint_vehicle(img, box, COLOURS[name][0])
    return img, np.array([b for b, _ in vehicles]), [n for _, n in vehicles]
