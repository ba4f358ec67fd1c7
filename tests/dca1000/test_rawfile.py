"""Raw capture files: whole frames only, padding tolerated, mismatching cfgs refused."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.drivers.dca1000.layout import FrameGeometry, RawLayout, cube_to_raw
from mmatch.drivers.dca1000.rawfile import RawCapture
from mmatch.errors import ParseError

G = FrameGeometry(RawLayout.FOUR_LANE, 4, (0, 1), (0, 1, 2, 3), 32)


def _frames(n: int, g: FrameGeometry = G) -> bytes:
    rng = np.random.default_rng(0)
    return b"".join(
        cube_to_raw(rng.integers(-100, 100, (g.num_loops, g.num_virtual, g.num_samples)) + 0j, g)
        for _ in range(n)
    )


def test_whole_frames_and_split_files(tmp_path):
    data = _frames(5)
    (tmp_path / "a_Raw_0.bin").write_bytes(data[: 2 * G.frame_bytes + 100])
    (tmp_path / "a_Raw_1.bin").write_bytes(data[2 * G.frame_bytes + 100 :])
    cap = RawCapture([tmp_path / "a_Raw_0.bin", tmp_path / "a_Raw_1.bin"], G)
    assert len(cap) == 5
    for k, f in enumerate(cap):
        assert f.tobytes() == data[k * G.frame_bytes : (k + 1) * G.frame_bytes]


def test_partial_frame_is_refused_with_the_sizes(tmp_path):
    p = tmp_path / "x.bin"
    p.write_bytes(_frames(3) + b"\x01" * 10)
    with pytest.raises(
        ParseError, match=r"not a whole number of 4096-byte frames \(3 frames \+ 10 bytes\)"
    ):
        RawCapture(p, G)


def test_zero_padding_of_the_last_packet_is_tolerated(tmp_path):
    p = tmp_path / "x.bin"
    p.write_bytes(_frames(3) + bytes(1000))
    cap = RawCapture(p, G)
    assert len(cap) == 3 and cap.padding_bytes == 1000


def test_more_frames_than_the_cfg_records_is_refused(tmp_path):
    p = tmp_path / "x.bin"
    p.write_bytes(_frames(4))
    with pytest.raises(ParseError, match="only 2"):
        RawCapture(p, G, expected_frames=2)


def test_data_on_disabled_lanes_means_the_cfg_is_wrong(tmp_path):
    p = tmp_path / "x.bin"
    p.write_bytes(_frames(2))  # recorded with 4 RX
    g2 = FrameGeometry(RawLayout.FOUR_LANE, 4, (0, 1), (0, 1), 32)  # cfg says 2 RX: same size
    with pytest.raises(ParseError, match="disabled RX lanes"):
        RawCapture(p, g2)


def test_empty_and_missing(tmp_path):
    p = tmp_path / "e.bin"
    p.write_bytes(b"")
    with pytest.raises(ParseError, match="no complete frame"):
        RawCapture(p, G)
    with pytest.raises(ParseError, match="cannot read"):
        RawCapture(tmp_path / "missing.bin", G)
