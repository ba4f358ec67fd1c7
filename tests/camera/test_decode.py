import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mmatch.drivers.camera.decode import decode_centernet, decode_yolov5, decode_yolov8, suppress
from mmatch.drivers.camera.nms import box_iou, nms


def _xyxy_to_cxcywh(b):
    b = np.asarray(b, np.float32)
    return np.stack(
        [(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2, b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]], 1
    )


TRUE = np.array([[100, 120, 220, 200], [300, 310, 420, 400], [500, 50, 600, 90]], np.float32)
CLS = np.array([2, 7, 2])
SCORE = np.array([0.9, 0.8, 0.7], np.float32)


def yolov8_output(n_anchors=400, nc=8, seed=0, extra=None):
    """(1, 4 + nc [+ extra], N): the true boxes, a shifted duplicate of each, low-score noise."""
    rng = np.random.default_rng(seed)
    d = 4 + nc + (0 if extra is None else 1)
    out = np.zeros((d, n_anchors), np.float32)
    out[:4] = _xyxy_to_cxcywh(rng.uniform(0, 600, (n_anchors, 4)).clip(0) + [[0, 0, 20, 20]]).T
    out[4 : 4 + nc] = rng.uniform(0, 0.1, (nc, n_anchors))
    idx = rng.choice(n_anchors, 6, replace=False)
    for k, (b, c, s) in enumerate(zip(TRUE, CLS, SCORE, strict=True)):
        out[:4, idx[k]] = _xyxy_to_cxcywh(b[None])[0]
        out[4 + c, idx[k]] = s
        out[:4, idx[k + 3]] = _xyxy_to_cxcywh(b[None] + 3)[0]  # duplicate, IoU ~0.9
        out[4 + c, idx[k + 3]] = s - 0.1
        if extra is not None:
            out[-1, idx[k]] = extra[k]
    return out[None], idx


def test_yolov8_decode_and_nms_recover_boxes_classes_scores():
    out, _ = yolov8_output()
    dec = suppress(decode_yolov8(out, 0.3), 0.5)
    assert len(dec) == 3
    np.testing.assert_allclose(dec.boxes, TRUE, atol=1e-3)
    np.testing.assert_array_equal(dec.classes, CLS)
    np.testing.assert_allclose(dec.scores, SCORE, atol=1e-6)
    assert dec.depth is None


def test_yolov8_class_filter_and_depth_column():
    out, _ = yolov8_output(extra=[12.5, 30.0, 44.0])
    dec = suppress(decode_yolov8(out, 0.3, classes=(7,), num_classes=8, depth_index=12), 0.5)
    assert len(dec) == 1 and dec.classes[0] == 7
    np.testing.assert_allclose(dec.boxes[0], TRUE[1], atol=1e-3)
    assert dec.depth[0] == pytest.approx(30.0)


def test_yolov5_decode_uses_objectness_times_class():
    nc = 4
    rng = np.random.default_rng(1)
    rows = np.zeros((300, 5 + nc), np.float32)
    rows[:, :4] = _xyxy_to_cxcywh(rng.uniform(0, 500, (300, 4)) + [[0, 0, 30, 30]])
    rows[:, 4] = rng.uniform(0, 0.2, 300)
    rows[:, 5:] = rng.uniform(0, 1, (300, nc))
    rows[10, :4] = _xyxy_to_cxcywh(TRUE[:1])[0]
    rows[10, 4] = 0.95
    rows[10, 5:] = [0.1, 0.0, 0.8, 0.05]
    rows[11, :4] = _xyxy_to_cxcywh(TRUE[1:2])[0]
    rows[11, 4] = 0.5  # obj 0.5 x cls 0.9 = 0.45
    rows[11, 5:] = [0.0, 0.9, 0.1, 0.0]
    dec = suppress(decode_yolov5(rows[None], 0.3), 0.5)
    assert len(dec) == 2
    np.testing.assert_allclose(dec.scores, [0.95 * 0.8, 0.45], atol=1e-6)
    np.testing.assert_array_equal(dec.classes, [2, 1])
    np.testing.assert_allclose(dec.boxes, TRUE[:2], atol=1e-3)
    # class filter: only class 1 scored -> the first anchor scores 0.95 * 0.0 and is dropped
    dec = decode_yolov5(rows[None], 0.3, classes=(1,))
    np.testing.assert_array_equal(dec.classes, [1])


def test_empty_outputs():
    out = np.zeros((1, 84, 100), np.float32)
    assert len(decode_yolov8(out, 0.25)) == 0
    assert len(suppress(decode_yolov5(np.zeros((1, 100, 85), np.float32), 0.25))) == 0
    assert len(decode_centernet(np.zeros((1, 3, 16, 16)), np.zeros((1, 2, 16, 16)))) == 0


def centernet_heads(logits=True):
    c, h, w = 3, 32, 40
    hm = np.full((1, c, h, w), 0.01, np.float32)
    wh = np.zeros((1, 2, h, w), np.float32)
    reg = np.zeros((1, 2, h, w), np.float32)
    dep = np.zeros((1, 1, h, w), np.float32)
    peaks = [
        (0, 10, 12, 0.9, 8.0, 5.0, 0.25, 0.5, 20.0),
        (2, 20, 30, 0.7, 6.0, 4.0, 0.75, 0.0, 35.0),
    ]
    for cls, y, x, s, bw, bh, ox, oy, d in peaks:
        hm[0, cls, y, x] = s
        hm[0, cls, y, x + 1] = s - 0.2  # a neighbour: not a local max
        wh[0, :, y, x] = (bw, bh)
        reg[0, :, y, x] = (ox, oy)
        dep[0, 0, y, x] = np.log(1.0 / d)  # CenterNet: depth = 1/sigmoid(o) - 1  <=>  o = -log(d)
    if logits:
        hm = np.log(hm / (1 - hm))
    return hm, wh, reg, dep, peaks


@pytest.mark.parametrize("logits", [True, False])
def test_centernet_peaks_sizes_offsets_depth(logits):
    hm, wh, reg, dep, peaks = centernet_heads(logits)
    dec = suppress(decode_centernet(hm, wh, reg, dep, stride=4.0, score_threshold=0.3), 0.5)
    assert len(dec) == 2
    for k, (cls, y, x, s, bw, bh, ox, oy, d) in enumerate(peaks):
        cx, cy = (x + ox) * 4, (y + oy) * 4
        np.testing.assert_allclose(
            dec.boxes[k], [cx - bw * 2, cy - bh * 2, cx + bw * 2, cy + bh * 2], atol=1e-3
        )
        assert dec.classes[k] == cls
        assert dec.scores[k] == pytest.approx(s, abs=1e-5)
        assert dec.depth[k] == pytest.approx(d, rel=1e-4)
    only = decode_centernet(hm, wh, reg, None, 4.0, 0.3, classes=(2,))
    assert len(only) == 1 and only.classes[0] == 2 and only.depth is None


def test_nms_greedy_and_class_aware():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30], [0, 0, 10, 10]], np.float32)
    scores = np.array([0.9, 0.8, 0.7, 0.6])
    np.testing.assert_array_equal(nms(boxes, scores, 0.5), [0, 2])
    np.testing.assert_array_equal(
        nms(boxes, scores, 0.5, classes=np.array([0, 1, 0, 0])), [0, 1, 2]
    )
    np.testing.assert_array_equal(nms(boxes, scores, 0.5, max_detections=1), [0])
    assert nms(np.zeros((0, 4)), np.zeros(0)).size == 0
    iou = box_iou(boxes[:1], boxes)
    assert iou[0, 0] == pytest.approx(1.0) and iou[0, 2] == 0.0
    assert iou[0, 1] == pytest.approx(81 / 119)


def test_nms_matches_bruteforce_on_random_boxes():
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 100, (200, 2))
    boxes = np.concatenate([xy, xy + rng.uniform(5, 30, (200, 2))], 1)
    scores = rng.uniform(0, 1, 200)
    keep = nms(boxes, scores, 0.4, max_detections=1000)
    iou = box_iou(boxes, boxes)
    # every dropped box overlaps a kept, higher-scoring box; kept boxes do not overlap each other
    kept = set(keep.tolist())
    for i in range(200):
        if i not in kept:
            assert any(iou[i, k] > 0.4 and scores[k] >= scores[i] for k in kept)
    sub = iou[np.ix_(keep, keep)]
    assert (sub[~np.eye(len(keep), dtype=bool)] <= 0.4).all()


def test_nms_matrix_and_loop_paths_agree(monkeypatch):
    import mmatch.drivers.camera.nms as nms_mod

    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 200, (300, 2))
    boxes = np.concatenate([xy, xy + rng.uniform(5, 40, (300, 2))], 1)
    scores = rng.uniform(0, 1, 300)
    classes = rng.integers(0, 3, 300)
    a = nms(boxes, scores, 0.4, classes=classes, max_detections=1000)
    monkeypatch.setattr(nms_mod, "_MATRIX_MAX", 0)
    b = nms(boxes, scores, 0.4, classes=classes, max_detections=1000)
    np.testing.assert_array_equal(a, b)
    full = nms(boxes, scores, 0.4, max_detections=1000)
    np.testing.assert_array_equal(nms(boxes, scores, 0.4, max_detections=7), full[:7])


def test_non_finite_and_empty_candidates_are_dropped():
    out, idx = yolov8_output(extra=[10.0, np.nan, 30.0])
    out[0, 0, idx[0]] = np.nan  # first true box: NaN centre
    dec = suppress(decode_yolov8(out, 0.3, num_classes=8, depth_index=12), 0.5)
    assert np.isfinite(dec.boxes).all() and np.isfinite(dec.depth).all()
    # box 0 (NaN centre) and box 1 (NaN depth) are dropped; their weaker duplicates (finite,
    # depth 0) remain, so each vehicle is still found once, with finite values
    assert len(dec) == 3
    zero = np.zeros((1, 12, 10), np.float32)
    zero[0, 4] = 0.9  # confident but zero-size boxes
    assert len(suppress(decode_yolov8(zero, 0.3))) == 0


@settings(max_examples=60, deadline=None)
@given(
    arrays(
        np.float32,
        (1, 10, 30),
        elements=st.one_of(
            st.floats(-1e4, 1e4, width=32), st.sampled_from([np.nan, np.inf, -np.inf])
        ),
    ),
)
def test_decode_never_emits_bad_boxes(raw):
    dec = suppress(decode_yolov8(raw, 0.25), 0.45)
    assert np.isfinite(dec.boxes).all() and np.isfinite(dec.scores).all()
    assert (dec.boxes[:, 2] > dec.boxes[:, 0]).all() and (dec.scores > 0.25).all()
