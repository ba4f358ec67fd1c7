"""Wire codec of the shared frame (version 3; version 2 still read): round trip to the quantisation step, caps, the
signature covering every byte before it, and no malformed frame accepted. (Forged, tampered,
replayed and stale frames are the receiver's checks: tests/edge/test_edge_auth.py.)"""

from __future__ import annotations

import hashlib
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mmatch.codec import (BACKGROUND_DTYPE, MAGIC, MOVING_DTYPE, POINT_DTYPE, SIGNATURE_BYTES, VEHICLE_DTYPE,
                          EncodeError, Limits, OverCaps, decode, encode, header, split_signature)
from mmatch.errors import DecodeError
from mmatch.shared import SharedFrame

# quantisation steps of format version 2 (as of version 1) (half of each is the worst rounding error)
STEP_POS, STEP_DOP, STEP_PX, STEP_DEPTH, STEP_SNR = 0.01, 0.01, 0.5, 0.01, 0.5
STEP_U8 = 1 / 255


def make_frame(seed: int = 0, V: int = 4, K: int = 17, B: int = 50, sender: str = "cav-7",
               M: int = 0) -> SharedFrame:
    rng = np.random.default_rng(seed)
    index = np.sort(rng.integers(0, V, K)).astype(np.int32) if V else np.zeros(0, np.int32)
    feats = np.hstack([rng.dirichlet(np.ones(16), V), rng.dirichlet(np.ones(8), V),
                       rng.dirichlet(np.ones(8), V)]) if V else np.zeros((0, 32))
    u1 = rng.uniform(0, 1200, V)
    v1 = rng.uniform(0, 650, V)
    boxes = np.column_stack([u1, v1, u1 + rng.uniform(5, 80, V), v1 + rng.uniform(5, 60, V),
                             rng.uniform(0, 1, V), rng.uniform(2, 95, V)])
    pts = np.column_stack([rng.uniform(-80, 80, K), rng.uniform(0, 100, K), rng.uniform(-3, 3, K),
                           rng.uniform(-40, 40, K), rng.uniform(0, 60, K)])
    return SharedFrame(sender=sender, seq=int(rng.integers(0, 2**63)), stamp=1.7e9 + rng.uniform(0, 1e4),
                       radar_height=0.73, ego_velocity=rng.uniform(-20, 20, 2),
                       vehicle_points=pts.astype(np.float32), vehicle_index=index,
                       vehicle_boxes=boxes.astype(np.float32),
                       vehicle_box_index=np.arange(V, dtype=np.int32) * 2,
                       vehicle_centers=rng.uniform(-50, 90, (V, 2)).astype(np.float32),
                       vehicle_features=feats.astype(np.float32),
                       background=rng.uniform(-100, 100, (B, 3)).astype(np.float32),
                       moving=rng.uniform(-90, 90, (M, 2)).astype(np.float32))


def assert_round_trip(a: SharedFrame, b: SharedFrame) -> None:
    half = 0.5 + 1e-3          # half a step, plus float32 slack
    assert b.sender == a.sender and b.seq == a.seq and b.stamp == a.stamp
    assert b.radar_height == pytest.approx(a.radar_height, rel=1e-6)
    assert np.all(np.abs(b.ego_velocity - a.ego_velocity) <= half * STEP_DOP)
    order = np.argsort(a.vehicle_index, kind="stable")
    np.testing.assert_array_equal(b.vehicle_index, a.vehicle_index[order])
    pa = a.vehicle_points[order]
    assert np.all(np.abs(b.vehicle_points[:, :3] - pa[:, :3]) <= half * STEP_POS)
    assert np.all(np.abs(b.vehicle_points[:, 3] - pa[:, 3]) <= half * STEP_DOP)
    assert np.all(np.abs(b.vehicle_points[:, 4] - np.clip(pa[:, 4], 0, 127.5)) <= half * STEP_SNR)
    assert np.all(np.abs(b.vehicle_boxes[:, :4] - a.vehicle_boxes[:, :4]) <= half * STEP_PX)
    assert np.all(np.abs(b.vehicle_boxes[:, 4] - a.vehicle_boxes[:, 4]) <= half * STEP_U8)
    assert np.all(np.abs(b.vehicle_boxes[:, 5] - a.vehicle_boxes[:, 5]) <= half * STEP_DEPTH)
    np.testing.assert_array_equal(b.vehicle_box_index, a.vehicle_box_index)
    assert b.moving.shape == a.moving.shape and np.all(np.abs(b.moving - a.moving) <= half * STEP_POS)
    assert np.all(np.abs(b.vehicle_centers - a.vehicle_centers) <= half * STEP_POS)
    assert np.all(np.abs(b.vehicle_features - a.vehicle_features) <= half * STEP_U8)
    assert np.all(np.abs(b.background - a.background) <= half * STEP_POS)
    assert b.vehicle_points.dtype == np.float32 and b.vehicle_index.dtype == np.int32
    assert b.vehicle_boxes.shape == a.vehicle_boxes.shape and b.background.shape == a.background.shape


@pytest.mark.parametrize("seed", range(5))
def test_round_trip_exact_to_the_quantisation_step(seed):
    a = make_frame(seed, M=seed * 7)
    data = encode(a)
    assert data[4] == 3                          # format version 3
    assert len(data) == (4 + 1 + 1 + 4 + 8 + 1 + len(a.sender) + 8 + 8 + 4 + 2 * 2 + 4 * 2 + 64
                         + 4 * VEHICLE_DTYPE.itemsize + 17 * POINT_DTYPE.itemsize
                         + 50 * BACKGROUND_DTYPE.itemsize + seed * 7 * MOVING_DTYPE.itemsize)
    assert_round_trip(a, decode(data))
    assert encode(decode(data)) == data          # quantised values are a fixed point


def as_version_2(data: bytes) -> bytes:
    """A version-3 frame without moving points rewritten as version 2 (no moving count)."""
    slen = data[18]
    counts_end = 19 + slen + 8 + 8 + 4 + 4 + 6           # V, K, B; M follows
    assert data[counts_end:counts_end + 2] == b"\x00\x00"
    body = data[:4] + bytes([2]) + data[5:counts_end] + data[counts_end + 2:-SIGNATURE_BYTES]
    return _reseal(body)


def test_a_version_2_frame_is_still_read_with_an_empty_moving_sketch():
    """A fleet upgrades one vehicle at a time: version-2 frames (no moving count, no moving
    records) decode as before; the header says which version came."""
    a = make_frame(5)
    old = as_version_2(encode(a))
    assert len(old) == len(encode(a)) - 2
    b = decode(old)
    assert_round_trip(a, b)
    assert b.moving.shape == (0, 2) and header(old).version == 2 and header(encode(a)).version == 3
    with pytest.raises(DecodeError, match="version 4"):
        decode(_reseal(encode(a)[:4] + bytes([4]) + encode(a)[5:-SIGNATURE_BYTES]))


def test_round_trip_unsorted_points_come_back_grouped_by_vehicle():
    a = make_frame(3)
    perm = np.random.default_rng(1).permutation(len(a.vehicle_index))
    a.vehicle_index, a.vehicle_points = a.vehicle_index[perm], a.vehicle_points[perm]
    b = decode(encode(a))
    assert np.all(np.diff(b.vehicle_index) >= 0)
    assert_round_trip(a, b)


def test_round_trip_empty_frame_and_unknown_velocity():
    a = SharedFrame(sender="", seq=0, stamp=0.0, radar_height=0.5, ego_velocity=np.full(2, np.nan))
    b = decode(encode(a))
    assert b.num_vehicles == 0 and len(b.vehicle_points) == 0 and len(b.background) == 0
    assert np.all(np.isnan(b.ego_velocity))
    assert b.vehicle_points.shape == (0, 5) and b.background.shape == (0, 3)


def test_round_trip_vehicles_without_points_and_unicode_sender():
    a = make_frame(4, V=3, K=0, B=0, sender="véhicule-ß")
    b = decode(encode(a))
    assert_round_trip(a, b)
    assert b.num_vehicles == 3 and len(b.vehicle_points) == 0


def test_quantisation_extremes_round_trip():
    a = make_frame(5, V=1, K=2, B=1)
    a.vehicle_points[0, :4] = [327.67, -327.68, 0.004, -327.68]
    a.vehicle_points[1, 4] = 500.0              # SNR clipped to 127.5 dB
    a.seq = 2**64 - 1
    b = decode(encode(a))
    assert_round_trip(a, b)
    assert b.vehicle_points[1, 4] == 127.5 and b.seq == 2**64 - 1


@pytest.mark.parametrize("field, value", [
    ("sender", "x" * 65), ("seq", -1), ("seq", 2**64), ("stamp", float("nan")),
    ("ego_velocity", np.array([1.0, np.nan])), ("ego_velocity", np.array([400.0, 0.0])),
    ("background", np.array([[400.0, 0.0, 0.0]], np.float32)),
])
def test_encode_refuses_what_the_wire_cannot_carry(field, value):
    a = make_frame(0)
    setattr(a, field, value)
    with pytest.raises(EncodeError, match=field.split("[")[0]):
        encode(a)


def test_encode_refuses_inconsistent_vehicle_index():
    a = make_frame(0)
    a.vehicle_index = a.vehicle_index.copy()
    a.vehicle_index[0] = 99
    with pytest.raises(EncodeError, match="vehicle_index"):
        encode(a)


# ---- every corrupted frame is rejected ----------------------------------------------------

def small_frame_bytes() -> bytes:
    return encode(make_frame(7, V=2, K=3, B=2, sender="c"))


class HashSigner:
    """A stand-in signer (SHA-512 of the message) to see what a signature covers."""

    key_id = b"\x01" * 8

    def sign(self, message: bytes) -> bytes:
        return hashlib.sha512(message).digest()


def test_the_signature_covers_every_byte_before_it():
    data = encode(make_frame(7, V=2, K=3, B=2, sender="c"), HashSigner())
    signed, sig = split_signature(data)
    assert len(sig) == SIGNATURE_BYTES and signed + sig == data
    assert sig == hashlib.sha512(data[:-SIGNATURE_BYTES]).digest()
    assert header(data).key_id == HashSigner.key_id
    unsigned = encode(make_frame(7, V=2, K=3, B=2, sender="c"))
    assert header(unsigned).key_id == bytes(8) and unsigned[-64:] == bytes(64)
    assert unsigned[18:-64] == data[18:-64]                   # the same frame either way


def test_every_single_byte_corruption_is_a_decode_error_or_a_frame():
    data = small_frame_bytes()
    assert len(data) > 100
    for pos in range(len(data)):
        for flip in (0x01, 0x80, 0xFF):
            bad = bytearray(data)
            bad[pos] ^= flip
            try:
                assert isinstance(decode(bytes(bad)), SharedFrame)
            except DecodeError:
                pass


def test_every_truncation_and_extension_is_rejected():
    data = small_frame_bytes()
    for cut in range(len(data)):
        with pytest.raises(DecodeError):
            decode(data[:cut])
    for extra in (b"\x00", b"\xff" * 3, data):
        with pytest.raises(DecodeError):
            decode(data + extra)


def _reseal(body: bytes) -> bytes:
    """Give a tampered frame (without its signature) a matching length and a zero signature."""
    body = body[:6] + struct.pack("<I", len(body) + 64) + body[10:]
    return body + bytes(64)


def test_counts_are_checked_against_the_bytes():
    data = small_frame_bytes()
    body = data[:-64]
    meta = 4 + 1 + 1 + 4 + 8 + 1 + 1         # header + key id + sender length + "c"
    counts_at = meta + 8 + 8 + 4 + 4         # seq, stamp, height, velocity
    for k in range(4):                       # V, K, B, M each off by one
        bad = bytearray(body)
        bad[counts_at + 2 * k] += 1
        with pytest.raises(DecodeError, match="counts"):
            decode(_reseal(bytes(bad)))
    # one vehicle claims one point more: the byte sizes agree, the per-vehicle sum does not
    veh_at = counts_at + 8
    n_points_at = veh_at + 8 + 1 + 2 + 2
    bad = bytearray(body)
    bad[n_points_at] += 1
    with pytest.raises(DecodeError, match="claim"):
        decode(_reseal(bytes(bad)))
    bad = bytearray(body)                    # sender length beyond the limit
    bad[18] = 200
    with pytest.raises(DecodeError):
        decode(_reseal(bytes(bad)))
    bad = bytearray(body)                    # invalid UTF-8 sender
    bad[19] = 0xFF
    with pytest.raises(DecodeError, match="UTF-8"):
        decode(_reseal(bytes(bad)))
    bad = bytearray(body)                    # NaN stamp
    bad[counts_at - 16:counts_at - 8] = struct.pack("<d", float("nan"))
    with pytest.raises(DecodeError, match="finite"):
        decode(_reseal(bytes(bad)))
    assert decode(_reseal(body)).sender == "c"      # the re-sealing itself is sound


def test_a_5000_vehicle_frame_is_refused_at_decode_before_its_records_are_read():
    rng = np.random.default_rng(0)
    V = 5000
    big = SharedFrame(sender="cav1", seq=1, stamp=1.0, radar_height=1.0,
                      vehicle_boxes=np.tile(np.array([[1, 1, 9, 9, 0.5, 20]], np.float32), (V, 1)),
                      vehicle_box_index=np.arange(V) % 65535,
                      vehicle_centers=rng.uniform(-50, 50, (V, 2)).astype(np.float32),
                      vehicle_features=np.zeros((V, 32), np.float32))
    data = encode(big)                     # the format can carry it ...
    with pytest.raises(OverCaps, match="too large"):
        decode(data)                       # ... a decoder refuses it on its size
    with pytest.raises(OverCaps, match="over the caps: 5000 vehicles"):
        header(data, Limits(max_vehicles=64, max_points=2048, max_background=100_000))
    assert isinstance(OverCaps("x"), DecodeError)


@pytest.mark.parametrize("kw, message", [
    ({"V": 5}, "5 vehicles"), ({"K": 11}, "11 points"), ({"B": 11}, "11 background"), ({"M": 11}, "11 moving"),
])
def test_counts_over_the_caps_are_refused(kw, message):
    limits = Limits(max_vehicles=4, max_points=10, max_background=10, max_moving=10)
    a = make_frame(2, V=kw.get("V", 2), K=kw.get("K", 3), B=kw.get("B", 3), M=kw.get("M", 3))
    with pytest.raises(OverCaps, match=message):
        decode(encode(a), limits)


@pytest.mark.parametrize("field", ["vehicle_points", "vehicle_centers", "background", "moving", "depth"])
def test_positions_beyond_the_radar_range_are_refused(field):
    a = make_frame(3, V=2, K=3, B=3, M=3)
    if field == "depth":
        a.vehicle_boxes[0, 5] = 160.0
    else:
        getattr(a, field)[0, 1] = -160.0
    data = encode(a)
    with pytest.raises(OverCaps, match="range"):
        decode(data, Limits(max_range_m=150.0))
    assert decode(data).sender == a.sender              # within the format's own range


@pytest.mark.parametrize("mutate, message", [
    (lambda d: b"XXXX" + d[4:], "magic"),
    (lambda d: d[:4] + b"\x01" + d[5:], "version"),      # version 1 (unsigned) is refused
    (lambda d: d[:5] + b"\x01" + d[6:], "flags"),
])
def test_header_errors_are_named(mutate, message):
    with pytest.raises(DecodeError, match=message):
        decode(mutate(small_frame_bytes()))


def test_non_bytes_input_is_a_decode_error():
    for junk in (None, 42, "MMSF", [1, 2, 3]):
        with pytest.raises(DecodeError):
            decode(junk)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=600))
def test_fuzz_random_bytes_only_raise_decode_error(data):
    with pytest.raises(DecodeError):
        decode(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_fuzz_bytes_behind_a_valid_header_only_raise_decode_error(tail):
    body = MAGIC + b"\x02\x00" + struct.pack("<I", 18 + len(tail) + 64) + bytes(8) + tail
    try:
        frame = decode(body + bytes(64))
    except DecodeError:
        return
    assert isinstance(frame, SharedFrame)   # a well-formed accident is fine; never another error


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), V=st.integers(0, 12), K=st.integers(0, 60), B=st.integers(0, 120),
       sender=st.text(max_size=20))
def test_round_trip_property(seed, V, K, B, sender):
    if V == 0:
        K = 0
    if len(sender.encode("utf-8")) > 64:
        sender = sender[:8]
    a = make_frame(seed, V=V, K=K, B=B, sender=sender)
    assert_round_trip(a, decode(encode(a)))
