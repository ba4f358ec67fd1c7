"""A small hard set shared by the report tests (made once per session)."""

from __future__ import annotations

import pytest

from mmatch.sim.generate import generate


@pytest.fixture(scope="session")
def small_hard(tmp_path_factory):
    out = tmp_path_factory.mktemp("report_hard")
    generate(out, 8, seed=3, mode="hard", jobs=1)
    return out
