"""One fusion's memo: what its matcher, aligner and confidence model each compute from the same
two frames (observations, radial ground speeds, road-speed consistency, descriptor distances)
is computed once inside `shared_block` (opened by `observations.observations_shared`).

Entries are keyed by the id() of the objects they derive from and keep those objects, so an id
reused by a new object never hits an old entry. Memoised arrays are read-only: a caller that
would change one in place fails loudly instead of changing it for the others.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

_MEMO: contextvars.ContextVar[dict | None] = contextvars.ContextVar("fusion_memo", default=None)


@contextlib.contextmanager
def shared_block() -> Iterator[None]:
    """Within this block `memo` computes each entry once. The objects it derives from must not
    change inside the block."""
    token = _MEMO.set({})
    try:
        yield
    finally:
        _MEMO.reset(token)


def _freeze(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, tuple):
        for v in value:
            _freeze(v)
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            _freeze(getattr(value, f.name))
    return value


def memo(name: str, sources: tuple, compute: Callable[[], T], *params: Any) -> T:
    """compute() once per (name, sources by identity, params) inside `shared_block`; outside
    it, every call computes."""
    table = _MEMO.get()
    if table is None:
        return compute()
    key = (name, *map(id, sources), *params)
    hit = table.get(key)
    if hit is None or any(a is not b for a, b in zip(hit[0], sources)):
        hit = table[key] = (sources, _freeze(compute()))
    return hit[1]
