"""The appearance descriptor of DESIGN.md: an HSV histogram of the pixels inside each box.

32 float32 per box: 16 hue bins over OpenCV's hue range [0, 180), then 8 saturation bins and
8 value bins over [0, 256); each of the three groups is normalised to sum to 1.

Boxes are clipped to the image. A box with no pixel left after clipping (outside the image,
zero or negative width/height, non-finite corners) gets the *uniform* descriptor (every bin of
a group equal to 1/bins), so every row always sums to 1 per group and never holds NaN.
"""

from __future__ import annotations

import numpy as np

from mmatch.types import DESCRIPTOR_DIM

HUE_BINS, SAT_BINS, VAL_BINS = 16, 8, 8
assert HUE_BINS + SAT_BINS + VAL_BINS == DESCRIPTOR_DIM

#: Descriptor of a box with no pixel (uniform in each group).
UNIFORM_DESCRIPTOR = np.concatenate(
    [
        np.full(HUE_BINS, 1 / HUE_BINS),
        np.full(SAT_BINS, 1 / SAT_BINS),
        np.full(VAL_BINS, 1 / VAL_BINS),
    ]
).astype(np.float32)

# Bin index per 8-bit channel value: hue 0..179 -> 0..15, saturation/value 0..255 -> 0..7.
_HUE_CODE = np.minimum(np.arange(256) * HUE_BINS // 180, HUE_BINS - 1).astype(np.uint8)
_SV_CODE = (np.arange(256) * SAT_BINS // 256).astype(np.uint8)


def clip_boxes(boxes: np.ndarray, width: int, height: int) -> np.ndarray:
    """Integer pixel bounds (M, 4) x0, y0, x1, y1 (half-open) of boxes clipped to the image.

    boxes: (M, >=4) u1, v1, u2, v2 in px (pixel centres at integer + 0.5 are not assumed:
    pixel column c covers [c, c+1)). Non-finite corners give an empty box (x0 == x1).
    """
    b = np.asarray(boxes, dtype=np.float64)[:, :4]
    finite = np.isfinite(b).all(axis=1)
    b = np.where(finite[:, None], b, 0.0)
    x0 = np.clip(np.floor(np.minimum(b[:, 0], b[:, 2])), 0, width)
    x1 = np.clip(np.ceil(b[:, 2]), 0, width)
    y0 = np.clip(np.floor(np.minimum(b[:, 1], b[:, 3])), 0, height)
    y1 = np.clip(np.ceil(b[:, 3]), 0, height)
    out = np.stack([x0, y0, x1, y1], axis=1).astype(np.int64)
    empty = (
        ~finite
        | (b[:, 2] <= b[:, 0])
        | (b[:, 3] <= b[:, 1])
        | (out[:, 2] <= out[:, 0])
        | (out[:, 3] <= out[:, 1])
    )
    out[empty] = 0
    return out


def hsv_descriptor(
    image_bgr: np.ndarray, boxes: np.ndarray, max_pixels: int | None = None
) -> np.ndarray:
    """HSV-histogram appearance descriptor per box (DESIGN.md "Conventions").

    image_bgr: uint8 (H, W, 3) BGR image (OpenCV order); a (H, W) grey image is accepted too.
    boxes: (M, >=4) u1, v1, u2, v2 in image pixels (extra columns such as score/depth ignored).
    max_pixels: if set, boxes with more pixels are sampled on a regular grid (every k-th row and
        column) down to about this many pixels; None (default) uses every pixel.
    Returns float32 (M, 32): 16 hue + 8 saturation + 8 value bins, each group summing to 1;
    an empty/degenerate box gets `UNIFORM_DESCRIPTOR`.
    """
    import cv2

    img = np.asarray(image_bgr)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) BGR, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got {img.dtype}")
    boxes = np.asarray(boxes)
    if boxes.ndim != 2 or boxes.shape[1] < 4:
        raise ValueError(f"boxes must be (M, >=4), got shape {boxes.shape}")
    m = len(boxes)
    out = np.empty((m, DESCRIPTOR_DIM), np.float32)
    if m == 0:
        return out
    h, w = img.shape[:2]
    bounds = clip_boxes(boxes, w, h)
    for i, (x0, y0, x1, y1) in enumerate(bounds.tolist()):
        if x1 <= x0 or y1 <= y0:
            out[i] = UNIFORM_DESCRIPTOR
            continue
        crop = img[y0:y1, x0:x1]
        if max_pixels is not None and crop.shape[0] * crop.shape[1] > max_pixels:
            step = int(np.ceil(np.sqrt(crop.shape[0] * crop.shape[1] / max_pixels)))
            crop = crop[::step, ::step]
        hsv = cv2.cvtColor(np.ascontiguousarray(crop), cv2.COLOR_BGR2HSV)
        n = float(hsv.shape[0] * hsv.shape[1])
        out[i, :HUE_BINS] = cv2.calcHist([hsv], [0], None, [HUE_BINS], [0, 180]).ravel() / n
        out[i, HUE_BINS : HUE_BINS + SAT_BINS] = (
            cv2.calcHist([hsv], [1], None, [SAT_BINS], [0, 256]).ravel() / n
        )
        out[i, HUE_BINS + SAT_BINS :] = (
            cv2.calcHist([hsv], [2], None, [VAL_BINS], [0, 256]).ravel() / n
        )
    return out


def hsv_descriptor_reference(image_bgr: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Slow, obviously correct numpy version of `hsv_descriptor` (tests; the definition)."""
    import cv2

    img = np.asarray(image_bgr)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    bounds = clip_boxes(np.asarray(boxes), img.shape[1], img.shape[0])
    out = np.empty((len(bounds), DESCRIPTOR_DIM), np.float32)
    for i, (x0, y0, x1, y1) in enumerate(bounds.tolist()):
        if x1 <= x0 or y1 <= y0:
            out[i] = UNIFORM_DESCRIPTOR
            continue
        px = hsv[y0:y1, x0:x1].reshape(-1, 3)
        hh = np.bincount(_HUE_CODE[px[:, 0]], minlength=HUE_BINS)
        ss = np.bincount(_SV_CODE[px[:, 1]], minlength=SAT_BINS)
        vv = np.bincount(_SV_CODE[px[:, 2]], minlength=VAL_BINS)
        out[i] = np.concatenate([hh, ss, vv]) / len(px)
    return out
