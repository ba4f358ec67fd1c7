"""Shared test settings: no network but loopback, and no library phoning home."""

from __future__ import annotations

import os
import socket

import pytest

from netutil import free_port

os.environ["DEPTHAI_TELEMETRY"] = "0"
os.environ["DEPTHAI_PROTOCOL"] = "usb"
os.environ["DEPTHAI_DISABLE_STARTUP_NOTIFICATIONS"] = "1"


@pytest.fixture
def tcp_port() -> int:
    return free_port()


@pytest.fixture
def udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)
