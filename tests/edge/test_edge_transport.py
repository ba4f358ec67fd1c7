"""Zenoh transport on 127.0.0.1: two peers, keys, foreign/malformed payloads, keep-newest."""

from __future__ import annotations

import threading
import time

import pytest

from mmatch.edge import keys
from mmatch.edge.config import ZenohSection
from mmatch.edge.transport import KeepNewest, Transport, zenoh_config_json
from mmatch.errors import ConfigError, DecodeError
from netutil import free_port



def test_key_expressions():
    assert keys.shared("cav1") == "mmatch/v1/cav1/shared"
    assert keys.fused("ego") == "mmatch/v1/ego/fused"
    assert keys.health("ego") == "mmatch/v1/ego/health"
    assert keys.all_of("shared") == "mmatch/v1/*/shared"
    assert keys.parse("mmatch/v1/cav1/shared") == ("cav1", "shared")
    assert keys.parse("mmatch/v2/cav1/shared") is None
    assert keys.parse("mmatch/v1/cav1/other") is None
    with pytest.raises(ConfigError):
        keys.shared("a/b")


def test_zenoh_settings_are_explicit():
    j = zenoh_config_json(ZenohSection(listen=["tcp/127.0.0.1:7000"]))
    assert j["listen/endpoints"] == ["tcp/127.0.0.1:7000"]
    assert j["scouting/multicast/enabled"] is False and j["scouting/gossip/enabled"] is False
    assert j["transport/shared_memory/enabled"] is False
    # a connect-only peer still sets listen explicitly (default would be every interface)
    assert zenoh_config_json(ZenohSection(connect=["tcp/127.0.0.1:7000"]))["listen/endpoints"] == []
    c = zenoh_config_json(ZenohSection(mode="client", connect=["tcp/127.0.0.1:7000"]))
    assert c["mode"] == "client" and "listen/endpoints" not in c
    with pytest.raises(ConfigError):
        zenoh_config_json(ZenohSection(mode="client"))


def test_keep_newest_drops_oldest():
    q: KeepNewest[int] = KeepNewest(3)
    for i in range(10):
        q.put(i)
    assert q.dropped == 7 and len(q) == 3
    assert [q.get(0), q.get(0), q.get(0), q.get(0.01)] == [7, 8, 9, None]
    for i in range(5):
        q.put(i)
    assert q.get_newest(0) == 4 and q.dropped == 7 + 2 + 2 and len(q) == 0


def test_keep_newest_wakes_a_waiting_reader():
    q: KeepNewest[str] = KeepNewest(1)
    threading.Timer(0.05, q.put, args=("x",)).start()
    assert q.get(5.0) == "x"
    threading.Timer(0.05, q.close).start()
    t0 = time.monotonic()
    assert q.get(5.0) is None and time.monotonic() - t0 < 4.0


def test_two_peers_exchange_and_count_bad_payloads():
    """A bad payload and a vehicle not listened to are dropped and counted, never delivered.

    Shared frames are published with congestion control DROP (a late frame is worth nothing), so
    on a loaded machine a sample can be lost on the way: like a CAV at its frame rate, the test
    sends again until each kind has arrived, and counts what it sent."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    got: list[tuple[str, bytes]] = []
    arrived = threading.Event()

    def on_payload(vehicle: str, payload: bytes) -> None:
        if payload.startswith(b"BAD"):
            raise DecodeError("bad magic")
        got.append((vehicle, payload))
        if ("cav1", b"one") in got and ("cav2", b"two") in got:   # ("first" may come too)
            arrived.set()

    def until(done, send) -> int:
        sent, deadline = 0, time.monotonic() + 5
        while not done() and time.monotonic() < deadline:
            send()
            sent += 1
            time.sleep(0.05)
        return sent

    with Transport(ZenohSection(listen=[ep])) as ego, Transport(ZenohSection(connect=[ep])) as cav:
        ego.subscribe(keys.all_of("shared"), "shared", on_payload, vehicles=["cav1", "cav2"])
        assert cav.wait_for_peers(5.0)
        cav.put(keys.shared("cav1"), b"first")  # declares the publisher
        deadline = time.monotonic() + 5
        while not cav.has_subscribers(keys.shared("cav1")) and time.monotonic() < deadline:
            time.sleep(0.01)
        foreign = until(lambda: ego.drops.snapshot().get("foreign", 0) >= 1,
                        lambda: cav.put(keys.shared("cav3"), b"not listened to"))
        bad = until(lambda: ego.drops.snapshot().get("malformed", 0) >= 1,
                    lambda: cav.put(keys.shared("cav1"), b"BAD frame"))
        until(arrived.is_set, lambda: (cav.put(keys.shared("cav1"), b"one"), cav.put(keys.shared("cav2"), b"two")))
        assert arrived.is_set()
        time.sleep(0.1)
        drops = ego.drops.snapshot()
    assert ("cav1", b"one") in got and ("cav2", b"two") in got
    assert all(not p.startswith(b"BAD") for _, p in got)
    assert {p for _, p in got} <= {b"first", b"one", b"two"}
    assert 1 <= drops.get("malformed", 0) <= bad
    assert 1 <= drops.get("foreign", 0) <= foreign


def test_close_is_safe_twice_and_leaves_nothing_open():
    from edge_proc import open_fds

    ep = f"tcp/127.0.0.1:{free_port()}"
    before = None
    for k in range(4):  # the first cycle starts zenoh's runtime (its threads and epolls stay)
        if k == 1:
            before = open_fds()
        a = Transport(ZenohSection(listen=[ep])).open()
        b = Transport(ZenohSection(connect=[ep])).open()
        assert b.wait_for_peers(5.0)
        b.put(keys.shared("x"), b"1")
        b.close()
        a.close()
        a.close()
    deadline = time.monotonic() + 5
    while open_fds() > before and time.monotonic() < deadline:
        time.sleep(0.05)
    assert open_fds() <= before


def test_client_mode_reaches_a_listening_node():
    """A client connects to one endpoint (a router in the field; here a listening peer)."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    got = threading.Event()
    with Transport(ZenohSection(listen=[ep])) as hub, \
            Transport(ZenohSection(mode="client", connect=[ep])) as client:
        hub.subscribe(keys.fused("ego1"), "fused", lambda v, p: got.set() if p == b"x" else None)
        assert client.wait_for_peers(5.0)
        deadline = time.monotonic() + 5
        while not got.is_set() and time.monotonic() < deadline:
            client.put(keys.fused("ego1"), b"x")
            time.sleep(0.05)
    assert got.is_set()
