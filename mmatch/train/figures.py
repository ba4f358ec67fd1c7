"""Per-epoch training figures drawn with OpenCV (no plotting library needed).

Left: training and validation loss by epoch (log scale). Middle: validation precision,
recall, F1 and top-k recall by epoch. Right: histogram of the validation scores of true
pairs (green) and false pairs (red, log counts).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

W, H, M = 360, 280, 36


def _panel(title: str) -> np.ndarray:
    img = np.full((H, W, 3), 255, np.uint8)
    cv2.rectangle(img, (M, 20), (W - 10, H - M), (200, 200, 200), 1)
    cv2.putText(img, title, (M, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def _line(img, xs, ys, lo, hi, n, colour, label, row):
    if len(xs) == 0:
        return
    x = M + (np.asarray(xs, float) / max(n - 1, 1)) * (W - 10 - M)
    y = (H - M) - (np.clip((np.asarray(ys, float) - lo) / max(hi - lo, 1e-9), 0, 1)) * (H - M - 20)
    pts = np.column_stack([x, y]).astype(np.int32)
    cv2.polylines(img, [pts], False, colour, 2, cv2.LINE_AA)
    cv2.putText(img, label, (W - 110, 36 + 14 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.38, colour, 1, cv2.LINE_AA)


def epoch_figure(path: str | Path, history: list, max_epochs: int) -> None:
    """Write the figure of the epochs so far (history: list of fit.EpochStats)."""
    n = max(max_epochs, 2)
    ep = [h.epoch for h in history]
    a = _panel("loss (log10)")
    losses = np.log10(np.maximum([h.train_loss for h in history] + [h.val_loss for h in history], 1e-6))
    lo, hi = float(losses.min()) - 0.05, float(losses.max()) + 0.05
    _line(a, ep, np.log10(np.maximum([h.train_loss for h in history], 1e-6)), lo, hi, n, (200, 80, 0), "train", 0)
    _line(a, ep, np.log10(np.maximum([h.val_loss for h in history], 1e-6)), lo, hi, n, (0, 0, 220), "validation", 1)
    b = _panel("validation pairs")
    for k, (key, col) in enumerate((("precision", (200, 80, 0)), ("recall", (0, 140, 0)), ("f1", (0, 0, 220)),
                                    ("topk_recall", (120, 0, 160)))):
        _line(b, ep, [getattr(h, key) for h in history], 0.5, 1.0, n, col, key, k)
    c = _panel(f"scores, epoch {history[-1].epoch}")
    bins = np.linspace(0, 1, 21)
    pos = np.histogram(history[-1].pos_scores, bins)[0]
    neg = np.histogram(history[-1].neg_scores, bins)[0]
    top = np.log10(max(pos.max(initial=1), neg.max(initial=1)) + 1)
    bw = (W - 10 - M) / 20
    for k in range(20):
        for counts, col, off in ((neg, (0, 0, 220), 0), (pos, (0, 150, 0), bw / 2)):
            h = np.log10(counts[k] + 1) / top * (H - M - 24)
            x0 = int(M + k * bw + off)
            cv2.rectangle(c, (x0, int(H - M - h)), (int(x0 + bw / 2 - 1), H - M), col, -1)
    cv2.imwrite(str(path), np.hstack([a, b, c]))
