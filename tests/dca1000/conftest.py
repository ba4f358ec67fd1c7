"""Fixtures of the DCA1000 tests: the AWR2243 cfg, small geometries, and a socket-leak guard."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest

HERE = Path(__file__).parent
CFG_PATH = HERE / "awr2243_3tx.cfg"


def _inet_inodes() -> set[str]:
    """Inodes of this process' TCP/UDP sockets (not netlink or unix ones that libraries such
    as libusb open from their own threads at any time)."""
    inodes = set()
    for table in ("tcp", "tcp6", "udp", "udp6"):
        try:
            with open(f"/proc/self/net/{table}") as f:
                next(f)
                inodes.update(line.split()[9] for line in f if line.strip())
        except OSError:
            continue
    return inodes


def _describe(leaked: set[str]) -> list[str]:
    """The /proc/self/net lines of leaked sockets (local and remote address, state)."""
    inodes = {x.split("[")[1].rstrip("]") for x in leaked}
    out = []
    for table in ("tcp", "tcp6", "udp", "udp6"):
        try:
            with open(f"/proc/self/net/{table}") as f:
                out += [f"{table}: {line.strip()}" for line in f if line.split()[9:10] and line.split()[9] in inodes]
        except OSError:
            continue
    return out


def _open_sockets() -> set[str]:
    out = set()
    inet = _inet_inodes()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:") and target[8:-1] in inet:
            out.add(f"{fd}:{target}")
    return out


@pytest.fixture(autouse=True)
def no_socket_left_open():
    """Fail the test that leaves a socket open."""
    before = _open_sockets()
    yield
    leaked = _open_sockets() - before
    deadline = time.monotonic() + 2.0
    while leaked and time.monotonic() < deadline:   # a thread of an earlier test still closing
        time.sleep(0.05)
        leaked = _open_sockets() - before
    assert not leaked, f"sockets left open: {sorted(leaked)} {_describe(leaked)}"


@pytest.fixture(scope="session")
def radar_cfg():
    from mmatch.drivers.ti.cfg import load_cfg

    logging.getLogger("mmatch.drivers.ti.cfg").setLevel(logging.ERROR)
    return load_cfg(CFG_PATH)


@pytest.fixture(scope="session")
def dsp_setup(radar_cfg):
    """(cfg, geometry, RadarDsp) for the AWR2243 3TX x 4RX cfg, CA-CFAR."""
    from mmatch.drivers.dca1000.dsp import make_dsp

    geom, dsp = make_dsp(radar_cfg)
    return radar_cfg, geom, dsp
