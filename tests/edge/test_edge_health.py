"""sd_notify over a real unix datagram socket, and the watchdog interval."""

from __future__ import annotations

import os
import socket

from mmatch.edge import health


def test_notify_messages_arrive_on_a_real_socket(tmp_path):
    path = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(path)
    srv.settimeout(2.0)
    n = health.Notifier(path)
    try:
        assert n.enabled
        assert n.ready("starting")
        assert n.watchdog()
        assert n.status("radar 20.0/s | drops x=1")
        assert n.stopping()
        got = [srv.recv(4096).decode() for _ in range(4)]
    finally:
        n.close()
        n.close()
        srv.close()
    assert got == ["READY=1\nSTATUS=starting", "WATCHDOG=1", "STATUS=radar 20.0/s | drops x=1", "STOPPING=1"]
    assert n.sent == 4


def test_abstract_socket_address():
    name = f"mmatch-test-{os.getpid()}"
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind("\0" + name)
    srv.settimeout(2.0)
    n = health.Notifier("@" + name)
    try:
        assert n.ready()
        assert srv.recv(100) == b"READY=1"
    finally:
        n.close()
        srv.close()


def test_no_socket_is_a_silent_no_op(monkeypatch):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = health.Notifier()
    assert not n.enabled and n.ready() is False and n.sent == 0


def test_unreachable_socket_does_not_raise(tmp_path):
    n = health.Notifier(str(tmp_path / "nobody.sock"))
    assert n.watchdog() is False
    n.close()


def test_watchdog_interval_is_half_of_watchdog_usec():
    assert health.watchdog_interval({"WATCHDOG_USEC": "10000000"}) == 5.0
    assert health.watchdog_interval({}) is None
    assert health.watchdog_interval({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}) == 1.0
    assert health.watchdog_interval({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}) is None


def test_status_line_has_rates_and_drops():
    s = health.format_status({"radar": 20.0, "fused": 19.5}, {"radar_queue": 2, "malformed": 1})
    assert s == "radar 20.0/s fused 19.5/s | drops malformed=1 radar_queue=2"
