"""Property: flips, insertions, deletions and truncation of a long stream never raise, and
every frame the mutations did not touch comes out exactly (ti_formats.md section 0)."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.ti.reader import read_all
from drivers.ti.writer import encode_frame

from .helpers import all_tlv_messages, make_points

FORMATS = ("sdk3", "sdk2", "xwr14xx", "toolbox", "pc3d")
N_FRAMES = 24


def _stream(fmt: str, seed: int) -> tuple[bytes, list[tuple[int, int, bytes]]]:
    """A stream of N_FRAMES frames; returns it and (start, end, frame bytes) per frame."""
    rng = np.random.default_rng(seed)
    extra = all_tlv_messages(seed)["pc3d" if fmt == "pc3d" else "oob"]
    chunks, spans, pos = [], [], 0
    for k in range(N_FRAMES):
        n = int(rng.integers(0, 40))
        tlvs = [extra[int(rng.integers(0, len(extra)))]] if k % 3 == 0 else []
        f = encode_frame(make_points(n, seed=seed * 1000 + k), 100 + k, fmt, extra_tlvs=tlvs)
        chunks.append(f)
        spans.append((pos, pos + len(f), f))
        pos += len(f)
    return b"".join(chunks), spans


mutation = st.tuples(st.sampled_from(["flip", "insert", "delete"]),
                     st.floats(0.0, 1.0, exclude_max=True),
                     st.binary(min_size=1, max_size=12),
                     st.integers(0, 7))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fmt=st.sampled_from(FORMATS), seed=st.integers(0, 3),
       mutations=st.lists(mutation, max_size=8),
       truncate=st.one_of(st.none(), st.floats(0.3, 1.0)),
       chunk=st.sampled_from([None, 1, 61, 4096]))
def test_mutations_cost_only_the_touched_frames(fmt, seed, mutations, truncate, chunk):
    data, spans = _stream(fmt, seed)
    buf = bytearray(data)
    # Track each original byte's position; None once a frame is touched.
    touched = [False] * len(spans)
    starts = np.array([s for s, _, _ in spans])
    shift = np.zeros(len(spans), np.int64)  # new start = start + shift

    def frame_of(orig_pos: int) -> int:
        return int(np.searchsorted(starts, orig_pos, side="right")) - 1

    # positions are drawn on the original stream and applied from the end backwards so
    # earlier positions stay valid.
    ops = sorted(((int(frac * len(data)), kind, blob, bit) for kind, frac, blob, bit in mutations),
                 key=lambda o: -o[0])
    for p, kind, blob, bit in ops:
        k = frame_of(p)
        if kind == "flip":
            buf[p] ^= 1 << bit
            touched[k] = True
        elif kind == "delete":
            del buf[p:p + len(blob)]
            for j in range(k, len(spans)):
                if spans[j][0] < p + len(blob):
                    touched[j] = True
            shift[starts > p] -= len(blob)
        else:  # insert before byte p: frame k is touched unless p is its first byte
            buf[p:p] = blob
            if p != spans[k][0]:
                touched[k] = True
            shift[starts >= p] += len(blob)
    mutated = bytes(buf)
    if truncate is not None:
        cut = int(truncate * len(mutated))
        mutated = mutated[:cut]
        for j, (s, e, _) in enumerate(spans):
            if s + shift[j] + (e - s) > cut:
                touched[j] = True

    packets, stats = read_all(mutated, chunk=chunk, on_error="skip")  # must not raise

    by_offset = {p.offset: p for p in packets}
    reference, _ = read_all(data)
    assert len(reference) == N_FRAMES
    for j, (s, e, raw) in enumerate(spans):
        if touched[j]:
            continue
        new = s + int(shift[j])
        assert mutated[new:new + len(raw)] == raw  # the bookkeeping above is right
        got = by_offset.get(new)
        assert got is not None, f"untouched frame {j} at {new} lost; rejections {stats.rejections}"
        ref = reference[j]
        assert got.length == len(raw) and got.header == ref.header
        np.testing.assert_array_equal(got.points, ref.points)
        assert got.tlvs == ref.tlvs
    assert stats.bytes_skipped + sum(p.length for p in packets) == len(mutated)
