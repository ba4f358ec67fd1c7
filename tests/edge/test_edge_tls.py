"""Done-when of issue 12, transport side, on 127.0.0.1: Zenoh over mutual TLS with the fleet's
certificates (`mmatch keys --tls`) and its access control: a peer without a valid certificate
cannot connect, and a client cannot publish under another vehicle's key (through a real
`mmatch router`, and vehicle to vehicle)."""

from __future__ import annotations

import signal
import threading
import time

import pytest
from edge_proc import start, stop, wait_for

from mmatch.edge import keys
from mmatch.edge.config import ZenohSection
from mmatch.edge.fleet import make_fleet
from mmatch.edge.transport import Transport
from mmatch.errors import ConfigError, DeviceError
from netutil import free_port


@pytest.fixture(scope="module")
def fleets(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tls")
    make_fleet(tmp / "fleet", ["cav1", "ego1"], tls=True, routers=["127.0.0.1"])
    make_fleet(tmp / "other", ["cav1"], tls=True)            # the same names, another CA
    return tmp


def _tls(folder, name, **kw) -> ZenohSection:
    tls = folder / "tls"
    return ZenohSection(tls_root_ca=str(tls / "ca.pem"), tls_certificate=str(tls / f"{name}.pem"),
                        tls_private_key=str(tls / f"{name}.key.pem"), **kw)


class Inbox:
    def __init__(self) -> None:
        self.keys: list[str] = []
        self.lock = threading.Lock()

    def __call__(self, sample) -> None:
        with self.lock:
            self.keys.append(str(sample.key_expr))

    def seen(self) -> set[str]:
        with self.lock:
            return set(self.keys)


def _publish_all(session: Transport, n: int = 10) -> None:
    for _ in range(n):
        for key in (keys.shared("cav1"), keys.fused("ego1"), keys.health("ego1"), keys.shared("cav2")):
            session.put(key, b"x" * 32)
        time.sleep(0.05)


def test_through_the_router_a_vehicle_publishes_only_under_its_own_key(fleets, tmp_path):
    fleet = fleets / "fleet"
    ep = f"tls/127.0.0.1:{free_port()}"
    router = start(["router", "--config", str(fleet / "zenoh" / "router.json5"), "--listen", ep],
                   tmp_path / "router.out")
    try:
        assert wait_for(lambda: "listening" in (tmp_path / "router.out").read_text(), 30), \
            (tmp_path / "router.out").read_text()
        inbox = Inbox()
        with Transport(_tls(fleet, "ego1", mode="client", connect=[ep])) as ego, \
                Transport(_tls(fleet, "cav1", mode="client", connect=[ep])) as cav:
            sub = ego.session.declare_subscriber("mmatch/v1/**", inbox)
            deadline = time.monotonic() + 10
            while keys.shared("cav1") not in inbox.seen() and time.monotonic() < deadline:
                _publish_all(cav, 1)
            _publish_all(cav)
            time.sleep(0.3)
            sub.undeclare()
        assert inbox.seen() == {keys.shared("cav1")}          # ego1's and cav2's keys refused
        # without a certificate, or with one from another CA, no session reaches the router
        for section in (ZenohSection(mode="client", connect=[ep]),
                        _tls(fleets / "other", "cav1", mode="client", connect=[ep])):
            with pytest.raises(DeviceError, match="cannot open session"):
                Transport(section).open().close()
    finally:
        stop(router, signal.SIGTERM)
        stop(router, signal.SIGKILL)


def test_vehicle_to_vehicle_mtls_and_access_control(fleets):
    fleet = fleets / "fleet"
    ep = f"tls/127.0.0.1:{free_port()}"
    acl = str(fleet / "zenoh" / "acl.json5")
    inbox = Inbox()
    with Transport(_tls(fleet, "ego1", listen=[ep], config_file=acl, tls_verify_name=False)) as ego:
        sub = ego.session.declare_subscriber("mmatch/v1/**", inbox)
        with Transport(_tls(fleet, "cav1", connect=[ep], config_file=acl, tls_verify_name=False)) as cav:
            assert cav.wait_for_peers(10)
            deadline = time.monotonic() + 10
            while keys.shared("cav1") not in inbox.seen() and time.monotonic() < deadline:
                _publish_all(cav, 1)
            _publish_all(cav)
            time.sleep(0.3)
        assert inbox.seen() == {keys.shared("cav1")}
        before = len(inbox.keys)
        for section in (ZenohSection(connect=[ep]),                           # plain TCP to a TLS port
                        _tls(fleets / "other", "cav1", connect=[ep], tls_verify_name=False)):
            with Transport(section) as intruder:
                assert not intruder.wait_for_peers(1.5)
                _publish_all(intruder, 3)
        time.sleep(0.3)
        assert len(inbox.keys) == before and not list(ego.session.info.peers_zid())
        sub.undeclare()


def test_tls_settings_are_checked_naming_the_key(fleets, tmp_path):
    from mmatch.edge import config

    fleet = fleets / "fleet"
    base = {"vehicle": {"id": "cav1"}, "zenoh": {"connect": ["tls/127.0.0.1:7447"],
                                                 "tls_root_ca": str(fleet / "tls" / "ca.pem")}}
    with pytest.raises(ConfigError, match="zenoh.tls_certificate"):
        config.from_dict(base)
    full = config.merge(base, {"zenoh": {"tls_certificate": str(tmp_path / "nope.pem"),
                                         "tls_private_key": str(fleet / "tls" / "cav1.key.pem")}})
    with pytest.raises(ConfigError, match=r"zenoh.connect\[0\]"):
        config.from_dict(config.merge(full, {"zenoh": {"connect": ["tcp/127.0.0.1:7447"]}}))
    with pytest.raises(ConfigError, match="zenoh.tls_certificate: .*nope.pem: no such file"):
        Transport(config.from_dict(full).zenoh).open()
