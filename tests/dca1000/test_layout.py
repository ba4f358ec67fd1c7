"""Raw ADC layouts (4-lane interleaved, 2-lane) to the (loops, virtual, samples) cube."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.drivers.dca1000.layout import (
    FrameGeometry,
    RawLayout,
    cube_to_raw,
    disabled_lane_energy,
    raw_to_cube,
)
from mmatch.errors import ConfigError, ParseError


def test_four_lane_interleaving_by_hand():
    g = FrameGeometry(
        RawLayout.FOUR_LANE, num_loops=1, tx_order=(0,), rx=(0, 1, 2, 3), num_samples=2
    )
    # sample 0: I(RX0..3) = 1 2 3 4, Q(RX0..3) = 5 6 7 8; sample 1: 11..14, 15..18
    raw = np.array([1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 13, 14, 15, 16, 17, 18], dtype="<i2").tobytes()
    cube = raw_to_cube(raw, g)
    assert cube.shape == (1, 4, 2)
    np.testing.assert_array_equal(cube[0, :, 0], [1 + 5j, 2 + 6j, 3 + 7j, 4 + 8j])
    np.testing.assert_array_equal(cube[0, :, 1], [11 + 15j, 12 + 16j, 13 + 17j, 14 + 18j])
    assert cube_to_raw(cube, g) == raw


def test_two_lane_pairs_by_hand():
    g = FrameGeometry(RawLayout.TWO_LANE, num_loops=1, tx_order=(0,), rx=(0, 1), num_samples=4)
    # per RX: I(0) I(1) Q(0) Q(1) I(2) I(3) Q(2) Q(3)
    rx0 = [1, 2, -1, -2, 3, 4, -3, -4]
    rx1 = [10, 20, -10, -20, 30, 40, -30, -40]
    raw = np.array(rx0 + rx1, dtype="<i2").tobytes()
    cube = raw_to_cube(raw, g)
    np.testing.assert_array_equal(cube[0, 0], [1 - 1j, 2 - 2j, 3 - 3j, 4 - 4j])
    np.testing.assert_array_equal(cube[0, 1], [10 - 10j, 20 - 20j, 30 - 30j, 40 - 40j])
    assert cube_to_raw(cube, g) == raw


def test_iq_swap():
    g = FrameGeometry(RawLayout.FOUR_LANE, 1, (0,), (0, 1, 2, 3), 1, iq_swap=True)
    raw = np.array([1, 2, 3, 4, 5, 6, 7, 8], dtype="<i2").tobytes()
    np.testing.assert_array_equal(raw_to_cube(raw, g)[0, :, 0], [5 + 1j, 6 + 2j, 7 + 3j, 8 + 4j])


def test_virtual_channel_order_follows_the_chirp_tx_order():
    """Chirp c carries value c + 1 on every sample and RX 'r' adds 100 r: virtual channel
    slot*4 + rx of loop l must hold chirp l*T + slot."""
    T, L, N = 3, 5, 8
    g = FrameGeometry(RawLayout.FOUR_LANE, L, (0, 2, 1), (0, 1, 2, 3), N)
    s = np.zeros((L * T, N, 2, 4), dtype="<i2")
    for c in range(L * T):
        for r in range(4):
            s[c, :, 0, r] = c + 1 + 100 * r
    cube = raw_to_cube(s.tobytes(), g)
    for loop in range(L):
        for slot in range(T):
            for r in range(4):
                assert cube[loop, slot * 4 + r, 0].real == loop * T + slot + 1 + 100 * r


@pytest.mark.parametrize("layout", list(RawLayout))
@pytest.mark.parametrize("rx", [(0, 1, 2, 3), (0, 2), (1,)])
def test_roundtrip_random(layout, rx):
    g = FrameGeometry(layout, 4, (0, 1, 2), rx, 16)
    rng = np.random.default_rng(1)
    cube = rng.integers(-3000, 3000, (4, 3 * len(rx), 16)) + 1j * rng.integers(
        -3000, 3000, (4, 3 * len(rx), 16)
    )
    raw = cube_to_raw(cube, g)
    assert len(raw) == g.frame_bytes
    np.testing.assert_array_equal(raw_to_cube(raw, g), cube.astype(np.complex64))
    assert disabled_lane_energy(raw, g) == 0


def test_four_lane_keeps_disabled_lanes():
    g = FrameGeometry(RawLayout.FOUR_LANE, 2, (0,), (0, 1), 8)
    assert g.frame_bytes == 2 * 4 * 8 * 4  # four lanes although two RX are enabled
    g2 = FrameGeometry(RawLayout.TWO_LANE, 2, (0,), (0, 1), 8)
    assert g2.frame_bytes == 2 * 2 * 8 * 4
    raw = bytearray(cube_to_raw(np.ones((2, 2, 8)), g))
    raw[6:8] = (77).to_bytes(2, "little")  # lane 3 of the first I group
    assert disabled_lane_energy(bytes(raw), g) == 77


def test_wrong_size_and_bad_geometry():
    g = FrameGeometry(RawLayout.FOUR_LANE, 2, (0,), (0, 1, 2, 3), 8)
    with pytest.raises(ParseError, match="implies"):
        raw_to_cube(bytes(g.frame_bytes - 4), g)
    with pytest.raises(ConfigError):
        FrameGeometry(RawLayout.TWO_LANE, 2, (0,), (0,), 7)
    with pytest.raises(ConfigError):
        FrameGeometry(RawLayout.FOUR_LANE, 2, (0,), (2, 1), 8)


def test_from_chirp(radar_cfg):
    g = FrameGeometry.from_chirp(radar_cfg.chirp)
    assert (g.num_loops, g.tx_order, g.rx, g.num_samples) == (128, (0, 1, 2), (0, 1, 2, 3), 256)
    assert g.frame_bytes == 384 * 4 * 256 * 4
