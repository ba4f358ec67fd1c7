"""Property: flips, insertions, deletions and truncation of a long stream never raise, and
every frame the mutations did not touch comes out exactly (ti_formats.md section 0)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from mmatch.drivers.ti.reader import read_all
from mmatch.drivers.ti.writer import encode_frame

from .helpers import all_tlv_messages, make_points

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # corrupt data: no numpy noise

FORMATS = ("sdk3", "sdk2", "sdk1", "xwr14xx", "toolbox", "pc3d")
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
    # origin[i]: index in `data` of the byte now at i (-1: inserted); flipped: touched bytes
    origin = np.arange(len(data), dtype=np.int64)
    flipped = np.zeros(len(data), bool)
    # positions are drawn on the original stream and applied from the end backwards
    ops = sorted(((int(frac * len(data)), kind, blob, bit) for kind, frac, blob, bit in mutations),
                 key=lambda o: -o[0])
    for p, kind, blob, bit in ops:
        if kind == "flip":
            if p < len(buf):
                buf[p] ^= 1 << bit
                if origin[p] >= 0:
                    flipped[origin[p]] = True
        elif kind == "delete":
            del buf[p:p + len(blob)]
            origin = np.delete(origin, np.arange(p, min(p + len(blob), len(origin))))
        else:  # insert before byte p
            buf[p:p] = blob
            origin = np.insert(origin, p, np.full(len(blob), -1))
    mutated = bytes(buf)
    if truncate is not None:
        cut = int(truncate * len(mutated))
        mutated, origin = mutated[:cut], origin[:cut]
    assert len(origin) == len(mutated)
    where = np.full(len(data), -1, np.int64)  # new position of each surviving original byte
    keep = origin >= 0
    where[origin[keep]] = np.nonzero(keep)[0]
    touched = []
    for s, e, _ in spans:
        new = where[s]
        intact = (new >= 0 and new + (e - s) <= len(origin)
                  and np.array_equal(origin[new:new + (e - s)], np.arange(s, e))
                  and not flipped[s:e].any())
        touched.append(not intact)
    shift = [int(where[s]) - s for s, _, _ in spans]
    event(f"untouched frames: {'>=12' if touched.count(False) >= 12 else '<12'}")
    event(f"touched frames: {'none' if not any(touched) else 'some'}")

    packets, stats = read_all(mutated, chunk=chunk, on_error="skip")  # must not raise

    by_offset = {p.offset: p for p in packets}
    reference, _ = read_all(data)
    assert len(reference) == N_FRAMES
    for j, (s, e, raw) in enumerate(spans):
        if touched[j]:
            continue
        new = s + shift[j]
        assert mutated[new:new + len(raw)] == raw  # the bookkeeping above is right
        got = by_offset.get(new)
        assert got is not None, f"untouched frame {j} at {new} lost; rejections {stats.rejections}"
        ref = reference[j]
        assert got.length == len(raw) and got.header == ref.header
        np.testing.assert_array_equal(got.points, ref.points)
        assert got.tlvs == ref.tlvs
    assert stats.bytes_skipped + sum(p.length for p in packets) == len(mutated)
