"""Fixtures of the DCA1000 tests: the AWR2243 cfg, small geometries, and a socket-leak guard."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

HERE = Path(__file__).parent
CFG_PATH = HERE / "awr2243_3tx.cfg"


def _open_sockets() -> set[str]:
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:"):
            out.add(f"{fd}:{target}")
    return out


@pytest.fixture(autouse=True)
def no_socket_left_open():
    """Fail the test that leaves a socket open."""
    before = _open_sockets()
    yield
    leaked = _open_sockets() - before
    assert not leaked, f"sockets left open: {sorted(leaked)}"


@pytest.fixture(scope="session")
def radar_cfg():
    from drivers.ti.cfg import load_cfg

    logging.getLogger("drivers.ti.cfg").setLevel(logging.ERROR)
    return load_cfg(CFG_PATH)


@pytest.fixture(scope="session")
def dsp_setup(radar_cfg):
    """(cfg, geometry, RadarDsp) for the AWR2243 3TX x 4RX cfg, CA-CFAR."""
    from drivers.dca1000.dsp import make_dsp

    geom, dsp = make_dsp(radar_cfg)
    return radar_cfg, geom, dsp
