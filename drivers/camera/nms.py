"""Non-maximum suppression on axis-aligned boxes (numpy, one vectorised IoU row per kept box)."""

from __future__ import annotations

import numpy as np

_MATRIX_MAX = 512  # up to this many candidates NMS uses one (K, K) IoU matrix


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU matrix (len(a), len(b)) of boxes x1, y1, x2, y2 (any unit; empty boxes give 0)."""
    a = np.asarray(a, np.float64)[:, None, :4]
    b = np.asarray(b, np.float64)[None, :, :4]
    iw = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    ih = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0, None)
    inter = iw * ih
    area_a = np.clip(a[..., 2] - a[..., 0], 0, None) * np.clip(a[..., 3] - a[..., 1], 0, None)
    area_b = np.clip(b[..., 2] - b[..., 0], 0, None) * np.clip(b[..., 3] - b[..., 1], 0, None)
    union = area_a + area_b - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    iou_threshold: float = 0.45,
    classes: np.ndarray | None = None,
    max_detections: int = 100,
) -> np.ndarray:
    """Greedy NMS. Returns int64 indices of the kept boxes, highest score first.

    boxes: (K, 4) x1, y1, x2, y2; scores: (K,); classes: optional (K,) ints — when given,
    boxes of different classes never suppress each other (class-aware NMS); None is
    class-agnostic. A box is dropped when its IoU with a kept, higher-scoring box exceeds
    `iou_threshold`. At most `max_detections` indices are returned.
    """
    boxes = np.asarray(boxes, np.float64)
    scores = np.asarray(scores)
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    if classes is not None:
        # Shift each class into its own region so that cross-class IoU is 0 (torchvision's trick).
        span = float(np.abs(boxes[:, :4]).max()) * 2 + 1
        boxes = boxes[:, :4] + (np.asarray(classes, np.float64) * span)[:, None]
    order = np.argsort(-scores, kind="stable")
    if len(order) <= _MATRIX_MAX:
        # Small candidate sets (the usual case after the score threshold): one IoU matrix, then a
        # cheap sequential pass over boolean rows.
        over = box_iou(boxes[order], boxes[order]) > iou_threshold
        alive = np.ones(len(order), bool)
        keep_sorted: list[int] = []
        for i in range(len(order)):
            if not alive[i]:
                continue
            keep_sorted.append(i)
            if len(keep_sorted) >= max_detections:
                break
            alive[i + 1 :] &= ~over[i, i + 1 :]
        return order[np.asarray(keep_sorted, np.int64)]
    x1, y1, x2, y2 = boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3]
    area = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    keep: list[int] = []
    while order.size and len(keep) < max_detections:
        i = int(order[0])
        keep.append(i)
        rest = order[1:]
        iw = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        ih = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = iw * ih
        union = area[i] + area[rest] - inter
        iou = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
        order = rest[iou <= iou_threshold]
    return np.asarray(keep, np.int64)
