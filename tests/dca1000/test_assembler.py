"""Frame reassembly: boundaries inside packets, loss, reordering, duplicates, bad byte counts."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mmatch.drivers.dca1000.assembler import FrameAssembler

P = 1456


def _stream(num_frames: int, frame_bytes: int, seed: int = 0) -> bytes:
    return (
        np.random.default_rng(seed)
        .integers(0, 256, num_frames * frame_bytes, dtype=np.uint8)
        .tobytes()
    )


def _packets(data: bytes, pad: bool = True) -> list[tuple[int, int, bytes]]:
    """(seq, byte count, payload) like the FPGA: seq from 1, last packet zero-padded."""
    out = []
    for i in range(-(-len(data) // P)):
        chunk = data[i * P : (i + 1) * P]
        if pad:
            chunk = chunk + bytes(P - len(chunk))
        out.append((i + 1, i * P, chunk))
    return out


def _run(asm: FrameAssembler, packets) -> list:
    frames = []
    for seq, bc, payload in packets:
        frames += asm.add(seq, bc, payload)
    return frames + asm.flush()


def _affected(lost_idx, frame_bytes: int, total: int) -> set[int]:
    out = set()
    for i in lost_idx:
        a, b = i * P, min((i + 1) * P, total)
        out.update(range(a // frame_bytes, (b - 1) // frame_bytes + 1))
    return out


def _check(frames, data: bytes, F: int, flagged_expected: set[int]) -> None:
    for f in frames:
        ref = np.frombuffer(data[f.index * F : (f.index + 1) * F], dtype=np.uint8)
        if f.complete:
            assert f.index not in flagged_expected
            assert np.array_equal(f.data, ref), f"frame {f.index} differs"
        else:
            # received bytes are exact, missing ones are zeros
            assert f.index in flagged_expected
            diff = f.data != ref
            assert not f.data[diff].any()
            assert f.missing_bytes >= int(diff.sum())
    assert {f.index for f in frames if not f.complete} == flagged_expected


@pytest.mark.parametrize(
    "F", [5000, 4 * P, 100_000]
)  # boundary inside packets, aligned, multi-packet
def test_in_order_stream_is_exact(F):
    data = _stream(7, F)
    asm = FrameAssembler(F, num_frames=7)
    frames = _run(asm, _packets(data))
    assert [f.index for f in frames] == list(range(7))
    _check(frames, data, F, set())
    assert asm.stats.frames_complete == 7 and asm.stats.gaps == 0


def test_loss_flags_exactly_the_affected_frames_and_zero_fills():
    F = 5000
    data = _stream(20, F, seed=1)
    pk = _packets(data)
    lost = {3, 4, 30, 68}  # 3 and 4 straddle frame boundaries
    frames = _run(
        asm := FrameAssembler(F, num_frames=20), [p for i, p in enumerate(pk) if i not in lost]
    )
    expected = _affected(lost, F, len(data))
    _check(frames, data, F, expected)
    assert [f.index for f in frames] == list(range(20))
    # 3-4 and 30 are gaps in the byte count; 68 is the last packet, seen only as a short frame 19
    assert asm.stats.frames_flagged == len(expected) and asm.stats.gaps == 2


def test_reordering_within_the_window_is_exact():
    F = 5000
    data = _stream(12, F, seed=2)
    pk = _packets(data)
    rng = np.random.default_rng(3)
    order = np.arange(len(pk))
    for start in range(0, len(order) - 8, 8):
        rng.shuffle(order[start : start + 8])
    asm = FrameAssembler(F, num_frames=12)
    frames = _run(asm, [pk[i] for i in order])
    _check(frames, data, F, set())
    assert asm.stats.out_of_order > 0 and asm.stats.frames_complete == 12


def test_duplicates_are_ignored():
    F = 5000
    data = _stream(4, F)
    pk = _packets(data)
    asm = FrameAssembler(F, num_frames=4)
    frames = _run(asm, pk[:6] + [pk[4], pk[5]] + pk[6:] + [pk[1]])
    _check(frames, data, F, set())
    assert asm.stats.duplicates == 2  # pk[4], pk[5]: frame 1 still open
    assert asm.stats.late == 1  # pk[1]: frame 0 already emitted


def test_contradicting_byte_count_is_dropped_without_shifting_later_frames():
    F = 5000
    data = _stream(10, F)
    pk = _packets(data)
    bad = list(pk)
    seq, bc, payload = bad[10]
    bad[10] = (seq, bc + 700, payload)  # impossible byte count for its sequence number
    bad[20] = (bad[20][0], bad[20][1], b"")  # empty payload
    bad[25] = (bad[25][0], bad[25][1], bytes(2000))  # longer than any DCA1000 payload
    asm = FrameAssembler(F, num_frames=10)
    frames = _run(asm, bad)
    _check(frames, data, F, _affected({10, 20, 25}, F, len(data)))
    assert asm.stats.bad_packets == 3


def test_absurd_jump_is_bad_without_seq_check():
    F = 5000
    data = _stream(6, F)
    pk = _packets(data)
    pk[5] = (pk[5][0], 10**12, pk[5][2])
    asm = FrameAssembler(F, num_frames=6, check_seq=False, max_jump_frames=100)
    frames = _run(asm, pk)
    _check(frames, data, F, _affected({5}, F, len(data)))
    assert asm.stats.bad_packets == 1


def test_drop_policy_withholds_incomplete_frames():
    F = 5000
    data = _stream(8, F)
    pk = _packets(data)
    asm = FrameAssembler(F, num_frames=8, policy="drop")
    frames = _run(asm, [p for i, p in enumerate(pk) if i != 9])
    assert all(f.complete for f in frames)
    assert {f.index for f in frames} == set(range(8)) - _affected({9}, F, len(data))
    assert asm.stats.frames_dropped == len(_affected({9}, F, len(data)))


def test_unknown_length_tail_is_truncated_not_emitted():
    F = 5000
    data = _stream(5, F)
    asm = FrameAssembler(F)  # number of frames unknown: padding opens a 6th frame
    frames = _run(asm, _packets(data))
    assert [f.index for f in frames] == [0, 1, 2, 3, 4] and all(f.complete for f in frames)
    assert asm.stats.frames_truncated == 1


def test_whole_frames_lost_are_counted_and_indices_show_the_gap():
    F = 3 * P
    data = _stream(10, F)
    pk = _packets(data)
    lost = set(range(9, 18))  # frames 3, 4, 5 entirely
    asm = FrameAssembler(F, num_frames=10, reorder_bytes=2 * P)
    frames = _run(asm, [p for i, p in enumerate(pk) if i not in lost])
    assert [f.index for f in frames] == [0, 1, 2, 6, 7, 8, 9]
    assert asm.stats.frames_lost == 3
    _check(frames, data, F, set())


def test_joining_mid_stream_flags_the_first_partial_frame():
    F = 5000
    data = _stream(6, F)
    pk = _packets(data)[5:]  # starts inside frame 1
    frames = _run(FrameAssembler(F, num_frames=6), pk)
    assert frames[0].index == 1 and not frames[0].complete
    _check(frames, data, F, {1})


def test_late_packet_after_give_up_is_counted():
    F = 5000
    data = _stream(30, F)
    pk = _packets(data)
    asm = FrameAssembler(F, num_frames=30, reorder_bytes=4 * P)
    late = pk[2]
    frames = _run(asm, pk[:2] + pk[3:60] + [late] + pk[60:])
    assert asm.stats.late == 1
    _check(frames, data, F, _affected({2}, F, len(data)))


@settings(max_examples=40, deadline=None)
@given(
    loss=st.sets(st.integers(0, 68), max_size=8),
    seed=st.integers(0, 1000),
    F=st.sampled_from([1000, 4999, 2 * P, 7000]),
)
def test_property_loss_and_local_reorder(loss, seed, F):
    data = _stream(-(-69 * P // F), F, seed=seed)
    pk = _packets(data)
    rng = np.random.default_rng(seed)
    order = np.arange(len(pk))
    for start in range(0, len(order) - 4, 4):
        rng.shuffle(order[start : start + 4])
    kept = [pk[i] for i in order if i not in loss]
    frames = _run(FrameAssembler(F, num_frames=len(data) // F), kept)
    expected = _affected({i for i in loss if i < len(pk)}, F, len(data))
    lost_whole = {
        k for k in expected if all(i in loss for i in range(k * F // P, ((k + 1) * F - 1) // P + 1))
    }
    _check(frames, data, F, expected - lost_whole)


@settings(max_examples=25, deadline=None)
@given(
    loss=st.sets(st.integers(0, 68), max_size=5), batch=st.integers(1, 70), seed=st.integers(0, 100)
)
def test_batches_match_packet_by_packet(loss, batch, seed):
    """add_batch (contiguous fast path or fallback) == add, packet by packet."""
    F = 4999
    data = _stream(-(-69 * P // F), F, seed=seed)
    pk = [p for i, p in enumerate(_packets(data)) if i not in loss]
    a1 = FrameAssembler(F, num_frames=len(data) // F)
    ref = _run(a1, pk)
    a2 = FrameAssembler(F, num_frames=len(data) // F)
    got = []
    for j in range(0, len(pk), batch):
        chunk = pk[j : j + batch]
        buf = np.zeros(len(chunk) * P, dtype=np.uint8)
        for i, (_, _, payload) in enumerate(chunk):
            buf[i * P : i * P + len(payload)] = np.frombuffer(payload, dtype=np.uint8)
        got += a2.add_batch(
            np.array([c[0] for c in chunk]),
            np.array([c[1] for c in chunk]),
            np.array([len(c[2]) for c in chunk]),
            buf,
            P,
        )
    got += a2.flush()
    assert [(f.index, f.complete, f.missing_bytes) for f in got] == [
        (f.index, f.complete, f.missing_bytes) for f in ref
    ]
    assert all(np.array_equal(a.data, b.data) for a, b in zip(got, ref, strict=True))
    assert a1.stats.as_dict() == a2.stats.as_dict()


def test_duplicate_after_fast_path_is_still_detected():
    F = 5000
    data = _stream(3, F)
    pk = _packets(data)
    asm = FrameAssembler(F, num_frames=3)
    frames = asm.add(*pk[0])
    buf = np.frombuffer(b"".join(p[2] for p in pk[1:6]), dtype=np.uint8)
    frames += asm.add_batch(
        np.array([p[0] for p in pk[1:6]]), np.array([p[1] for p in pk[1:6]]), np.full(5, P), buf, P
    )
    frames += asm.add(*pk[5])  # duplicate of a packet that came in the batch (frame 1 still open)
    for p in pk[6:]:
        frames += asm.add(*p)
    frames += asm.flush()
    assert asm.stats.duplicates == 1
    _check(frames, data, F, set())
