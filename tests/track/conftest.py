"""Simulated sequences shared by the tracking tests (made once per session)."""

from __future__ import annotations

import pytest

from mmatch.sim.generate import generate_sequences


@pytest.fixture(scope="session")
def short_sequences(tmp_path_factory):
    """Two wide-physics drives of 12 frames each, written as files; returns (folder, scenes)."""
    out = tmp_path_factory.mktemp("sequences")
    return out, generate_sequences(out, 2, 12, seed=21, mode="hard", physics="wide")
