"""Shared test settings: no network but loopback, and no library phoning home."""

from __future__ import annotations

import os
import socket

import pytest

os.environ["DEPTHAI_TELEMETRY"] = "0"
os.environ["DEPTHAI_PROTOCOL"] = "usb"
os.environ["DEPTHAI_DISABLE_STARTUP_NOTIFICATIONS"] = "1"


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port on 127.0.0.1 that is free right now (TCP by default, SOCK_DGRAM for UDP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def tcp_port() -> int:
    return free_port()


@pytest.fixture
def udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)
