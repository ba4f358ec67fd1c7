"""Decoding raw detector outputs into boxes (network-input pixels), before NMS.

Supported layouts (batch size 1):

- ``yolov5``: one output (1, N, 5 + C [+ extra]) per anchor: cx, cy, w, h (input px),
  objectness, C class probabilities (sigmoid already applied, as Ultralytics exports do).
  Score = objectness x class probability.
- ``yolov8``: one output (1, 4 + C [+ extra], N): cx, cy, w, h, C class scores. Score = class score.
- ``centernet``: heatmap (1, C, h, w) (logits or probabilities), size ``wh`` (1, 2, h, w) in
  heatmap cells, optional sub-cell offset ``reg`` (1, 2, h, w) and optional depth ``dep``
  (1, 1, h, w). Peaks are the 3x3 local maxima above the threshold (the paper's max-pool NMS).

With a class filter only those classes are scored (score = max over the allowed classes).
An extra per-box depth (metres) is read from column `depth_index` (YOLO) or the ``dep``
output (CenterNet, transformed by 1/sigmoid(x) - 1 as in "Objects as Points" unless told
the output is already metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.drivers.camera.nms import nms

KINDS = ("yolov5", "yolov8", "centernet")


@dataclass
class Decoded:
    """Candidate boxes of one image in network-input pixels.

    boxes: float32 (K, 4) x1, y1, x2, y2; scores: float32 (K,); classes: int32 (K,);
    depth: float32 (K,) metres from the model, or None when the model gives none.
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    depth: np.ndarray | None = None

    def take(self, idx: np.ndarray) -> Decoded:
        return Decoded(
            self.boxes[idx],
            self.scores[idx],
            self.classes[idx],
            None if self.depth is None else self.depth[idx],
        )

    def __len__(self) -> int:
        return len(self.scores)


def _empty(with_depth: bool) -> Decoded:
    return Decoded(
        np.zeros((0, 4), np.float32),
        np.zeros(0, np.float32),
        np.zeros(0, np.int32),
        np.zeros(0, np.float32) if with_depth else None,
    )


def _cxcywh_to_xyxy(c: np.ndarray) -> np.ndarray:
    """(K, 4) cx, cy, w, h -> x1, y1, x2, y2 (float32)."""
    c = c.astype(np.float32, copy=False)
    half = c[:, 2:4] * 0.5
    with np.errstate(invalid="ignore", over="ignore"):  # inf/NaN outputs are dropped by suppress()
        return np.concatenate([c[:, 0:2] - half, c[:, 0:2] + half], axis=1)


def _top_k(scores: np.ndarray, k: int) -> np.ndarray:
    if len(scores) <= k:
        return np.arange(len(scores))
    return np.argpartition(-scores, k - 1)[:k]


def yolo_num_classes(width: int, kind: str, num_classes: int | None) -> int:
    """Number of class columns of a YOLO output whose per-anchor vector has `width` values."""
    fixed = 5 if kind == "yolov5" else 4
    return width - fixed if num_classes is None else num_classes


def decode_yolov5(
    out: np.ndarray,
    score_threshold: float = 0.25,
    classes: tuple[int, ...] | None = None,
    num_classes: int | None = None,
    depth_index: int | None = None,
    top_k: int = 1000,
) -> Decoded:
    """YOLOv5-style output (1, N, 5 + C [+ extra]) -> candidates above `score_threshold`."""
    a = np.asarray(out)
    a = a.reshape(a.shape[-2], a.shape[-1])
    nc = yolo_num_classes(a.shape[1], "yolov5", num_classes)
    obj = a[:, 4]
    cand = np.flatnonzero(obj > score_threshold)  # score <= obj, so this filter is exact
    if cand.size == 0:
        return _empty(depth_index is not None)
    rows = a[cand]
    cls_cols = rows[:, 5 : 5 + nc] if classes is None else rows[:, [5 + c for c in classes]]
    best = np.argmax(cls_cols, axis=1)
    with np.errstate(invalid="ignore", over="ignore"):
        scores = rows[:, 4] * cls_cols[np.arange(len(rows)), best]
    keep = np.flatnonzero(scores > score_threshold)
    keep = keep[_top_k(scores[keep], top_k)]
    rows, best, scores = rows[keep], best[keep], scores[keep]
    cls_ids = best if classes is None else np.asarray(classes)[best]
    depth = None if depth_index is None else rows[:, depth_index].astype(np.float32)
    return Decoded(
        _cxcywh_to_xyxy(rows[:, :4]), scores.astype(np.float32), cls_ids.astype(np.int32), depth
    )


def decode_yolov8(
    out: np.ndarray,
    score_threshold: float = 0.25,
    classes: tuple[int, ...] | None = None,
    num_classes: int | None = None,
    depth_index: int | None = None,
    top_k: int = 1000,
) -> Decoded:
    """YOLOv8-style output (1, 4 + C [+ extra], N) -> candidates above `score_threshold`."""
    a = np.asarray(out)
    a = a.reshape(a.shape[-2], a.shape[-1])
    nc = yolo_num_classes(a.shape[0], "yolov8", num_classes)
    cls_rows = a[4 : 4 + nc] if classes is None else a[[4 + c for c in classes]]
    scores_all = cls_rows.max(axis=0)
    cand = np.flatnonzero(scores_all > score_threshold)
    if cand.size == 0:
        return _empty(depth_index is not None)
    cand = cand[_top_k(scores_all[cand], top_k)]
    cols = a[:, cand]  # (D, K)
    cls_c = cols[4 : 4 + nc] if classes is None else cols[[4 + c for c in classes]]
    best = np.argmax(cls_c, axis=0)
    cls_ids = best if classes is None else np.asarray(classes)[best]
    depth = None if depth_index is None else cols[depth_index].astype(np.float32)
    return Decoded(
        _cxcywh_to_xyxy(cols[:4].T),
        scores_all[cand].astype(np.float32),
        cls_ids.astype(np.int32),
        depth,
    )


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def decode_centernet(
    heatmap: np.ndarray,
    wh: np.ndarray,
    reg: np.ndarray | None = None,
    dep: np.ndarray | None = None,
    stride: float = 4.0,
    score_threshold: float = 0.25,
    classes: tuple[int, ...] | None = None,
    apply_sigmoid: bool | None = None,
    depth_is_metres: bool = False,
    top_k: int = 100,
) -> Decoded:
    """CenterNet heads -> candidates (network-input px = heatmap cell x `stride`).

    heatmap: (1, C, h, w); apply_sigmoid None decides from the values (any outside [0, 1]
    means logits). wh: (1, 2, h, w) box width/height in cells; reg: (1, 2, h, w) sub-cell
    offset of the centre (0 when None); dep: (1, 1, h, w) depth head.
    """
    hm = np.asarray(heatmap)
    hm = hm.reshape(hm.shape[-3:])
    cls_map = np.arange(hm.shape[0]) if classes is None else np.asarray(classes)
    if classes is not None:
        hm = hm[list(classes)]
    if apply_sigmoid is None:
        apply_sigmoid = bool(hm.min() < 0.0 or hm.max() > 1.0)
    thr = (
        float(np.log(score_threshold / (1 - score_threshold))) if apply_sigmoid else score_threshold
    )
    flat = np.flatnonzero(hm > thr)  # (much faster than np.nonzero on a 3-D array)
    if flat.size == 0:
        return _empty(dep is not None)
    nc, h, w = hm.shape
    c, y, x = np.unravel_index(flat, hm.shape)
    # 3x3 local maximum test at the candidates only (same result as max-pool NMS on the map).
    padded = np.pad(hm, ((0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
    v = hm[c, y, x]
    is_peak = np.ones(c.size, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                is_peak &= v >= padded[c, y + 1 + dy, x + 1 + dx]
    c, y, x, v = c[is_peak], y[is_peak], x[is_peak], v[is_peak]
    sel = _top_k(v, top_k)
    c, y, x, v = c[sel], y[sel], x[sel], v[sel]
    scores = _sigmoid(v.astype(np.float64)) if apply_sigmoid else v
    size = np.asarray(wh).reshape(2, h, w)[:, y, x]
    off = np.zeros((2, len(y))) if reg is None else np.asarray(reg).reshape(2, h, w)[:, y, x]
    cx, cy = x + off[0], y + off[1]
    boxes = (
        np.stack([cx - size[0] / 2, cy - size[1] / 2, cx + size[0] / 2, cy + size[1] / 2], axis=1)
        * stride
    )
    depth = None
    if dep is not None:
        d = np.asarray(dep).reshape(h, w)[y, x].astype(np.float64)
        depth = (d if depth_is_metres else 1.0 / _sigmoid(d) - 1.0).astype(np.float32)
    return Decoded(
        boxes.astype(np.float32), scores.astype(np.float32), cls_map[c].astype(np.int32), depth
    )


def suppress(
    dec: Decoded, iou_threshold: float = 0.45, agnostic: bool = True, max_detections: int = 100
) -> Decoded:
    """NMS over decoded candidates (class-agnostic by default: a car and a truck box on the same
    vehicle are one vehicle). Returns the kept candidates, highest score first.

    Candidates with a non-finite coordinate, score or depth, or with zero/negative size, are
    dropped first (a broken model output never becomes a NaN box downstream)."""
    ok = (
        np.isfinite(dec.boxes).all(axis=1)
        & np.isfinite(dec.scores)
        & (dec.boxes[:, 2] > dec.boxes[:, 0])
        & (dec.boxes[:, 3] > dec.boxes[:, 1])
    )
    if dec.depth is not None:
        ok &= np.isfinite(dec.depth)
    if not ok.all():
        dec = dec.take(np.flatnonzero(ok))
    keep = nms(
        dec.boxes, dec.scores, iou_threshold, None if agnostic else dec.classes, max_detections
    )
    return dec.take(keep)
