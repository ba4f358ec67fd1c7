"""Streaming reader: named corrupt-stream fixtures, chunking, counters, bad-input policy."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from mmatch.drivers.ti.reader import TlvReader, read_all
from mmatch.drivers.ti.writer import encode_frame, encode_stream
from mmatch.errors import DecodeError

from .helpers import make_points, named_fixtures

FIXTURES = named_fixtures()


@pytest.mark.parametrize("name", sorted(FIXTURES))
@pytest.mark.parametrize("chunk", [None, 1, 7, 100])
def test_named_fixture(name, chunk):
    data, want = FIXTURES[name]
    packets, st = read_all(data, chunk=chunk)
    assert [p.header.frame_number for p in packets] == want["frames"]
    assert dict(st.rejected) == want["rejected"]
    assert st.bytes_skipped == want["skipped"]
    assert st.frames == len(want["frames"])
    assert st.bytes_in == len(data)
    assert st.restarts == want.get("restarts", 0)
    # accepted + skipped bytes account for the whole stream
    assert sum(p.length for p in packets) + st.bytes_skipped == len(data)


def test_rejections_carry_stream_offsets():
    data, _ = FIXTURES["dropped_byte.bin"]
    packets, st = read_all(data, chunk=13)
    first_len = packets[0].length
    assert st.rejections == [(first_len, "magic_inside_packet")]
    assert [p.offset for p in packets][:1] == [0]
    assert packets[1].offset == len(data) - packets[1].length - packets[2].length


def test_points_survive_chunking_exactly():
    frames = [make_points(n, seed=n) for n in (0, 3, 50, 7)]
    data = encode_stream(frames, "sdk3", first_frame=1)
    a, _ = read_all(data)
    b, _ = read_all(data, chunk=5)
    assert len(a) == len(b) == 4
    for pa, pb, src in zip(a, b, frames):
        np.testing.assert_array_equal(pa.points, pb.points)
        np.testing.assert_array_equal(pa.points[:, :4], src[:, :4])


def test_incomplete_frame_waits_for_bytes():
    f = encode_frame(make_points(20), 5, "sdk3")
    r = TlvReader(on_error="skip")
    assert r.feed(f[:100]) == []
    assert r.stats.rejected_total == 0 and r.stats.bytes_skipped == 0
    out = r.feed(f[100:])
    assert [p.header.frame_number for p in out] == [5]
    assert r.finish() == [] and r.stats.bytes_skipped == 0


def test_host_time_is_receive_time():
    t = iter([100.0, 200.0])
    r = TlvReader(clock=lambda: next(t))
    a = r.feed(encode_frame(make_points(2), 1))
    b = r.feed(encode_frame(make_points(2), 2))
    assert a[0].host_time == 100.0 and b[0].host_time == 200.0
    rf = r.to_radar_frame(b[0])
    assert rf.host_time == 200.0 and rf.frame_number == 2 and rf.points.shape == (2, 5)


def test_frame_gaps_and_tlv_counters():
    data = b"".join(encode_frame(make_points(3), fn, "sdk3") for fn in (1, 2, 5, 6))
    _, st = read_all(data)
    assert st.frame_gaps == 2 and st.restarts == 0
    assert dict(st.tlv_types) == {1: 4, 7: 4}
    d = st.as_dict()
    assert d["tlv_types"] == {"1": 4, "7": 4} and d["formats"] == {"h40": 4}


def test_policy_log_skip_raise(caplog):
    data, _ = FIXTURES["second_magic_inside.bin"]
    with caplog.at_level(logging.WARNING, logger="mmatch.drivers.ti.reader"):
        read_all(data, on_error="log")
    assert "magic_inside_packet" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="mmatch.drivers.ti.reader"):
        read_all(data, on_error="skip")
    assert caplog.text == ""
    r = TlvReader(on_error="raise")
    errors, fns = [], []
    chunks = [data] + [b""] * 5
    for chunk in chunks:  # the reader stays usable after each error
        try:
            fns += [p.header.frame_number for p in r.feed(chunk)]
        except DecodeError as exc:
            errors.append(str(exc))
    fns += [p.header.frame_number for p in r.finish()]
    assert fns == [10, 12]
    assert len(errors) == 2 and "magic_inside_packet" in errors[0] and "bad_length" in errors[1]
    assert r.stats.frames == 2 and r.stats.rejected_total == 2


def test_pure_garbage_never_raises():
    rng = np.random.default_rng(3)
    junk = rng.integers(0, 256, 200_000, dtype=np.uint8).tobytes()
    magic_rich = (b"\x02\x01\x04\x03\x06\x05\x08\x07" + junk[:40]) * 500
    for data in (junk, magic_rich, b"", b"\x02"):
        packets, st = read_all(data, chunk=4096)
        assert st.bytes_skipped + sum(p.length for p in packets) == len(data)
    _, st = read_all(magic_rich)
    assert st.frames == 0 and st.rejected_total == 500


def test_bad_policy_name():
    with pytest.raises(ValueError):
        TlvReader(on_error="ignore")


def test_decoder_bug_is_counted_not_raised(monkeypatch, caplog):
    import mmatch.drivers.ti.reader as reader_mod

    calls = {"n": 0}
    real = reader_mod.decode_frame

    def flaky(buf, offset, **kw):
        calls["n"] += 1
        if calls["n"] == 2:
            raise IndexError("boom")
        return real(buf, offset, **kw)

    monkeypatch.setattr(reader_mod, "decode_frame", flaky)
    data = b"".join(encode_frame(make_points(3), fn) for fn in (1, 2, 3))
    with caplog.at_level(logging.ERROR, logger="mmatch.drivers.ti.reader"):
        packets, st = read_all(data)
    assert [p.header.frame_number for p in packets] == [1, 3]
    assert dict(st.rejected) == {"internal_error": 1} and "boom" in caplog.text


def test_malformed_side_tlv_costs_only_itself():
    from mmatch.drivers.ti.tlv import RawTlv, Stats

    pts = make_points(4, seed=2)
    odd_stats = RawTlv(6, bytes(20))       # STATS should be 24 B
    odd_profile = RawTlv(2, bytes(7))      # RANGE_PROFILE is u16 per bin
    data = encode_frame(pts, 1, "sdk3", extra_tlvs=[odd_stats, odd_profile, Stats(1, 2, 3, 4, 5, 6)])
    packets, st = read_all(data)
    assert len(packets) == 1 and st.rejected_total == 0
    pkt = packets[0]
    assert pkt.malformed_tlvs == (6, 2)
    np.testing.assert_array_equal(pkt.points[:, :4], pts[:, :4])
    assert pkt.tlvs[2] == odd_stats and pkt.tlvs[4] == Stats(1, 2, 3, 4, 5, 6)
    assert st.malformed_tlvs == 2 and st.unknown_tlvs == 0


def test_subframes_share_a_frame_number_without_restart():
    pts = make_points(2)
    seq = [(1, 0), (1, 1), (2, 0), (2, 1), (4, 0), (4, 1), (0, 0)]
    data = b"".join(encode_frame(pts, fn, "sdk3", sub_frame_number=sub) for fn, sub in seq)
    packets, st = read_all(data)
    assert [(p.header.frame_number, p.header.sub_frame_number) for p in packets] == seq
    assert st.restarts == 1 and st.frame_gaps == 1


def test_wrong_port_or_baud_hint_logged_once(caplog):
    rng = np.random.default_rng(0)
    junk = rng.integers(0, 256, 200_000, dtype=np.uint8).tobytes()
    r = TlvReader(on_error="skip")
    with caplog.at_level(logging.WARNING, logger="mmatch.drivers.ti.reader"):
        for k in range(0, len(junk), 10_000):
            r.feed(junk[k:k + 10_000])
    hints = [rec for rec in caplog.records if "baud" in rec.getMessage()]
    assert len(hints) == 1 and "921600" in hints[0].getMessage()


def test_tiny_unpadded_sdk1_frames_back_to_back():
    from mmatch.drivers.ti.header import FrameHeader, HeaderFormat

    def bare(fn, fmt, size):  # SDK 1.x: header only, no TLVs, no padding
        return FrameHeader(fmt, 0x01020000, size, 0xA1642, fn, 0).to_bytes()

    data = bare(1, HeaderFormat.H40, 40) + bare(2, HeaderFormat.H40, 40) + bare(3, HeaderFormat.H40, 40)
    for chunk in (None, 1, 9):
        packets, st = read_all(data, chunk=chunk)
        assert [p.header.frame_number for p in packets] == [1, 2, 3], chunk
        assert st.rejected_total == 0 and all(p.points.shape == (0, 5) for p in packets)
    h36 = b"".join(FrameHeader(HeaderFormat.H36, 0x01000000, 36, 0xA1443, fn, 0).to_bytes()
                   for fn in (7, 8))
    packets, st = read_all(h36, chunk=5)
    assert [(p.header.frame_number, p.header.size) for p in packets] == [(7, 36), (8, 36)]


def test_big_frame_in_small_reads_and_cut_short():
    from mmatch.drivers.ti.tlv import RangeDopplerHeatMap

    heat = RangeDopplerHeatMap(np.arange(300_000, dtype=np.uint32).astype("<u2"))
    big = encode_frame(make_points(10), 1, "sdk3", extra_tlvs=[heat])
    nxt = encode_frame(make_points(3), 2, "sdk3")
    r = TlvReader(on_error="skip")
    got = []
    for k in range(0, len(big), 700):
        got += r.feed(big[k:k + 700])
    assert [p.header.frame_number for p in got] == [1] and got[0].tlvs[2] == heat
    # the same frame losing its tail, then the next frame: rejected as soon as it shows
    r = TlvReader(on_error="skip")
    cut = big[:400_000] + nxt
    got = []
    for k in range(0, len(cut), 700):
        got += r.feed(cut[k:k + 700])
    assert [p.header.frame_number for p in got] == [2]
    assert dict(r.stats.rejected) == {"magic_inside_packet": 1} and r.stats.bytes_skipped == 400_000
