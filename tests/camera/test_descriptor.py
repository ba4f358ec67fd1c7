import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mmatch.drivers.camera.descriptor import (
    HUE_BINS,
    SAT_BINS,
    UNIFORM_DESCRIPTOR,
    clip_boxes,
    hsv_descriptor,
    hsv_descriptor_reference,
)

from .camera_synth import COLOURS, painted_scene


def _groups(d):
    return d[:, :HUE_BINS], d[:, HUE_BINS : HUE_BINS + SAT_BINS], d[:, HUE_BINS + SAT_BINS :]


def test_matches_numpy_definition_on_random_image_and_boxes():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    x = rng.uniform(-50, 350, (40, 2))
    y = rng.uniform(-50, 280, (40, 2))
    boxes = np.stack([x.min(1), y.min(1), x.max(1), y.max(1)], 1).astype(np.float32)
    d = hsv_descriptor(img, boxes)
    assert d.dtype == np.float32 and d.shape == (40, 32)
    np.testing.assert_allclose(d, hsv_descriptor_reference(img, boxes), atol=1e-6)
    for g in _groups(d):
        np.testing.assert_allclose(g.sum(1), 1.0, atol=1e-5)


def test_single_colour_box_fills_expected_bins():
    img = np.zeros((100, 100, 3), np.uint8)
    img[:, :] = (200, 60, 30)  # saturated blue: H = 120 (bin 10), S = 218 (bin 6), V = 200 (bin 6)
    d = hsv_descriptor(img, np.array([[10, 10, 50, 60]], np.float32))[0]
    assert d[120 * 16 // 180] == pytest.approx(1.0)
    assert d[16 + 218 // 32] == pytest.approx(1.0)
    assert d[24 + 200 // 32] == pytest.approx(1.0)


def test_partial_box_at_border_uses_only_inside_pixels():
    img = np.zeros((100, 100, 3), np.uint8)
    img[:, :50] = (30, 30, 200)  # red left half
    img[:, 50:] = (200, 60, 30)  # blue right half
    # Box sticking out on the left: the inside part [0, 50) is all red.
    d = hsv_descriptor(img, np.array([[-80, 10, 50, 90], [50, -5, 180, 200]], np.float32))
    assert d[0, 0] == pytest.approx(1.0)  # red hue bin 0
    assert d[1, 120 * 16 // 180] == pytest.approx(1.0)  # blue only
    np.testing.assert_allclose(
        clip_boxes(np.array([[-80, 10, 50, 90]]), 100, 100), [[0, 10, 50, 90]]
    )


@pytest.mark.parametrize(
    "box",
    [
        [10, 10, 10, 50],
        [30, 30, 20, 40],
        [200, 200, 300, 300],
        [-50, -50, -1, -1],
        [np.nan, 0, 10, 10],
        [0, 0, np.inf, 10],
    ],
)
def test_degenerate_box_gives_uniform_descriptor(box):
    img = np.full((100, 100, 3), 128, np.uint8)
    d = hsv_descriptor(img, np.array([box], np.float32))
    np.testing.assert_array_equal(d[0], UNIFORM_DESCRIPTOR)
    assert np.isfinite(d).all()


def test_empty_and_grey_and_extra_columns():
    img = np.full((50, 60), 77, np.uint8)
    assert hsv_descriptor(img, np.zeros((0, 6), np.float32)).shape == (0, 32)
    d = hsv_descriptor(img, np.array([[0, 0, 60, 50, 0.9, 12.0]], np.float32))
    assert d[0, 0] == 1.0 and d[0, 16] == 1.0 and d[0, 24 + 77 // 32] == 1.0


def test_rejects_wrong_image():
    with pytest.raises(ValueError, match="uint8"):
        hsv_descriptor(np.zeros((10, 10, 3), np.float32), np.zeros((1, 4)))
    with pytest.raises(ValueError, match="BGR"):
        hsv_descriptor(np.zeros((10, 10, 4), np.uint8), np.zeros((1, 4)))


def test_subsampling_stays_close():
    img, boxes, _ = painted_scene()
    full = hsv_descriptor(img, boxes)
    sub = hsv_descriptor(img, boxes, max_pixels=2000)
    assert np.abs(full - sub).max() < 0.05


def test_painted_vehicles_are_told_apart_by_colour():
    img, boxes, names = painted_scene()
    d = hsv_descriptor(img, boxes)
    # The dominant hue bin of each saturated body is its colour's hue bin.
    for i, name in enumerate(names):
        assert np.argmax(d[i, :HUE_BINS]) == COLOURS[name][1] * HUE_BINS // 180, name
    # The two red cars are closer to each other than to any other colour.
    dist = np.abs(d[:, None] - d[None]).sum(-1)
    red = [i for i, n in enumerate(names) if n == "red"]
    others = [i for i, n in enumerate(names) if n != "red"]
    assert dist[red[0], red[1]] < 0.5 * dist[red[0], others].min()


@settings(max_examples=80, deadline=None)
@given(
    st.integers(1, 40),
    st.integers(1, 40),
    arrays(
        np.float64,
        st.tuples(st.integers(0, 6), st.just(4)),
        elements=st.one_of(st.floats(-100, 100), st.sampled_from([np.nan, np.inf, -np.inf])),
    ),
    st.integers(0, 2**32 - 1),
)
def test_any_boxes_give_normalised_finite_descriptors(w, h, boxes, seed):
    img = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    d = hsv_descriptor(img, boxes)
    assert d.shape == (len(boxes), 32) and np.isfinite(d).all() and (d >= 0).all()
    for g in _groups(d):
        np.testing.assert_allclose(g.sum(1), 1.0, atol=1e-5)
    np.testing.assert_allclose(d, hsv_descriptor_reference(img, boxes), atol=1e-6)
