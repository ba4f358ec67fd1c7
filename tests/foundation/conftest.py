"""Small simulated data sets shared by the foundation tests (made once per session)."""

from __future__ import annotations

import pytest

from mmatch.sim.generate import generate


@pytest.fixture(scope="session")
def hard_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("hard")
    generate(out, 30, seed=11, mode="hard", jobs=1)
    return out


@pytest.fixture(scope="session")
def mixed_scenes(tmp_path_factory):
    out = tmp_path_factory.mktemp("mixed")
    return generate(out, 40, seed=12, mode="mixed", jobs=1)


@pytest.fixture(scope="session")
def wide_mixed_scenes(tmp_path_factory):
    """Mixed scenes under the wide physics family (what the realism targets of issue 10 are for)."""
    out = tmp_path_factory.mktemp("wide-mixed")
    return generate(out, 80, seed=13, mode="mixed", jobs=1, physics="wide")
