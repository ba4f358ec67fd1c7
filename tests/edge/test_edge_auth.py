"""Trust between vehicles: signed frames and messages, the trust file, every refusal counted.

Done-when of issue 12: a frame signed with an unknown key, a tampered frame, a replayed frame,
a stale frame and a frame from the future are each refused and counted, while genuine frames
keep flowing at 20 Hz (the last test: over Zenoh on 127.0.0.1, into a real Node).
"""

from __future__ import annotations

import dataclasses
import struct
import threading
import time

import numpy as np
import pytest
from edge_fakes import FAKE, process_view

from mmatch import codec
from mmatch.edge import auth, config, keys
from mmatch.edge.auth import Rejected, Signer, TrustStore, Verifier
from mmatch.edge.config import ZenohSection
from mmatch.edge.logschema import SensorFrame
from mmatch.edge.node import Node
from mmatch.edge.sources.base import default_camera
from mmatch.edge.transport import Transport
from mmatch.errors import ConfigError
from netutil import free_port

NOW = 1_800_000_000.0


class Clock:
    def __init__(self, t: float = NOW) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def fleet(tmp_path):
    """Keys of cav1 and ego1 in a trust file, and an outsider's key not in it."""
    pubs = {v: auth.generate_key(tmp_path / f"{v}.key") for v in ("cav1", "ego1", "mallory")}
    auth.write_trust(tmp_path / "trust.toml", {"cav1": [pubs["cav1"]], "ego1": [pubs["ego1"]]})
    signers = {v: Signer.from_file(v, tmp_path / f"{v}.key") for v in pubs}
    return tmp_path, signers


def _frame(sender="cav1", seq=1, stamp=NOW, **kw):
    sf, _ = process_view(np.full((3, 5), 7.0, np.float32), None, None, None, 1.0, stamp,
                         sender=sender, seq=seq)
    return dataclasses.replace(sf, **kw)


def _verifier(path, clock=None, **kw):
    return Verifier(TrustStore(path / "trust.toml"), ahead_s=0.05, behind_s=0.15,
                    clock=clock or Clock(), **kw)


def test_genuine_frames_pass_and_each_forgery_is_refused_by_reason(fleet):
    path, s = fleet
    v = _verifier(path)
    good = codec.encode(_frame(seq=10), s["cav1"])
    assert v.open_frame("cav1", good).seq == 10
    cases = {
        "replay": good,                                                     # the same frame again
        "unknown_key": codec.encode(_frame(seq=11), Signer("cav1", s["mallory"]._key)),
        "unknown_sender": codec.encode(_frame("mallory", seq=11), s["mallory"]),
        "future": codec.encode(_frame(seq=12, stamp=NOW + 0.2), s["cav1"]),
        "stale": codec.encode(_frame(seq=13, stamp=NOW - 1.0), s["cav1"]),
        "caps": codec.encode(_frame(seq=14, vehicle_points=np.zeros((5000, 5), np.float32),
                                    vehicle_index=np.zeros(5000, np.int32)), s["cav1"]),
        "size": codec.encode(_frame(seq=14), s["cav1"]) + bytes(300_000),
    }
    unsigned = codec.encode(_frame(seq=15))
    cases_unknown = {"unknown_key": unsigned}                               # all-zero key id
    tampered = bytearray(codec.encode(_frame(seq=16), s["cav1"]))
    tampered[-80] ^= 0x01                                                   # a record byte
    for reason, data in [*cases.items(), *cases_unknown.items(), ("bad_signature", bytes(tampered))]:
        with pytest.raises(Rejected) as exc:
            v.open_frame("cav1" if reason != "unknown_sender" else "mallory", data)
        assert exc.value.reason == reason, (reason, str(exc.value))
    with pytest.raises(Rejected, match="sender_mismatch"):
        v.open_frame("ego1", codec.encode(_frame(seq=17), s["cav1"]))     # cav1's frame under ego1's key
    # the refusals did not move the sequence: the next genuine frame still passes
    assert v.open_frame("cav1", codec.encode(_frame(seq=11), s["cav1"])).seq == 11
    assert v.snapshot() == {"accepted": 2, "replay": 1, "unknown_key": 2, "unknown_sender": 1,
                            "future": 1, "stale": 1, "size": 1, "caps": 1, "bad_signature": 1,
                            "sender_mismatch": 1}


def test_every_byte_of_a_signed_frame_is_covered(fleet):
    path, s = fleet
    data = codec.encode(_frame(seq=5), s["cav1"])
    for pos in range(len(data)):
        bad = bytearray(data)
        bad[pos] ^= 0x20
        v = _verifier(path)
        with pytest.raises(Rejected):
            v.open_frame("cav1", bytes(bad))


def test_caps_refuse_a_signed_frame_over_them(fleet):
    path, s = fleet
    limits = codec.Limits(max_vehicles=4, max_points=10, max_background=10, max_range_m=100.0)
    v = _verifier(path, limits=limits)
    many = _frame(seq=1, vehicle_boxes=np.zeros((5, 6), np.float32), vehicle_box_index=np.arange(5),
                  vehicle_centers=np.zeros((5, 2), np.float32), vehicle_features=np.zeros((5, 32), np.float32))
    with pytest.raises(Rejected, match="over the caps"):
        v.open_frame("cav1", codec.encode(many, s["cav1"]))
    far = _frame(seq=2, background=np.array([[0.0, 120.0, 0.0]], np.float32))
    with pytest.raises(Rejected, match="range"):
        v.open_frame("cav1", codec.encode(far, s["cav1"]))
    assert v.snapshot() == {"caps": 2}


def test_key_rotation_without_restart_and_a_broken_trust_file_keeps_the_old_keys(fleet):
    path, s = fleet
    clock = Clock()
    t_mono = [0.0]
    trust = TrustStore(path / "trust.toml", monotonic=lambda: t_mono[0])
    v = Verifier(trust, ahead_s=0.05, behind_s=0.15, clock=clock)
    new_pub = auth.generate_key(path / "cav1-new.key")
    new = Signer.from_file("cav1", path / "cav1-new.key")
    with pytest.raises(Rejected, match="unknown_key"):
        v.open_frame("cav1", codec.encode(_frame(seq=1), new))
    auth.write_trust(path / "trust.toml", {"cav1": [new_pub], "ego1": [s["ego1"].public_raw]})
    t_mono[0] += 1.5                                           # the next poll sees the change
    assert v.open_frame("cav1", codec.encode(_frame(seq=2), new)).seq == 2
    with pytest.raises(Rejected, match="unknown_key"):          # the retired key is out
        v.open_frame("cav1", codec.encode(_frame(seq=3), s["cav1"]))
    (path / "trust.toml").write_text("[vehicles]\ncav1 = [\"not base64!\"]\n")
    trust.request_reload()                                     # as SIGHUP does
    assert v.open_frame("cav1", codec.encode(_frame(seq=4), new)).seq == 4
    assert trust.reload_errors == 1 and trust.loads == 2


@pytest.mark.parametrize("text, key", [
    ("[vehicles]\ncav1 = []\n", "vehicles.cav1"),
    ("[vehicles]\ncav1 = [\"AAAA\"]\n", "vehicles.cav1[0]"),
    ("[fleet]\n", "fleet"),
    ("vehicles = 3\n", "vehicles"),
    ("[vehicles\n", "not valid TOML"),
])
def test_a_bad_trust_file_names_the_entry(tmp_path, text, key):
    (tmp_path / "t.toml").write_text(text)
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        TrustStore(tmp_path / "t.toml")
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="UTF-8"):
        TrustStore(tmp_path / "bin.toml")
    with pytest.raises(ConfigError, match="folder"):
        TrustStore(tmp_path)


def test_signed_messages_cannot_be_forged_replayed_or_passed_off_as_another_kind(fleet):
    path, s = fleet
    v = _verifier(path)
    body = b'{"status":"fused","confidence":null}'
    msg = auth.seal_message(s["ego1"], "fused", body, 7, NOW)
    assert v.open_message("ego1", "fused", msg) == {"status": "fused", "confidence": None}
    with pytest.raises(Rejected, match="replay"):
        v.open_message("ego1", "fused", msg)
    with pytest.raises(Rejected, match="sender_mismatch"):
        v.open_message("ego1", "health", auth.seal_message(s["ego1"], "fused", body, 8, NOW))
    forged = auth.seal_message(Signer("ego1", s["mallory"]._key), "fused", body, 9, NOW)
    with pytest.raises(Rejected, match="unknown_key"):
        v.open_message("ego1", "fused", forged)
    bad = bytearray(auth.seal_message(s["ego1"], "fused", body, 10, NOW))
    bad[40] ^= 1
    with pytest.raises(Rejected, match="bad_signature"):
        v.open_message("ego1", "fused", bytes(bad))
    with pytest.raises(Rejected, match="malformed"):
        v.open_message("ego1", "fused", b"{\"status\": \"fused\"}" * 10)   # plain JSON: unsigned


def test_sequence_keeps_increasing_across_a_restart():
    t = [5_000_000]
    a = auth.Sequence(lambda: t[0])
    first = [a.next() for _ in range(100)]                    # faster than the clock ticks
    assert first == list(range(5_000_000, 5_000_100))
    t[0] += 50_000                                            # restart 50 ms later
    assert auth.Sequence(lambda: t[0]).next() > first[-1]


def test_dev_keys_are_made_on_first_start_and_trusted_by_the_other_simulated_vehicles(tmp_path):
    dev = tmp_path / "dev"
    cfg = {"auth": {"dev_dir": str(dev)}, "radar": {"source": "sim"}}
    ego = auth.identity(config.from_dict({**cfg, "vehicle": {"id": "ego1", "role": "ego"}}))
    cav = auth.identity(config.from_dict({**cfg, "vehicle": {"id": "cav1", "role": "cav"}}))
    assert ego.mode == cav.mode == "dev" and "DEV KEYS" in ego.describe()["warning"]
    assert (dev / "cav1.key").stat().st_mode & 0o077 == 0 and dev.stat().st_mode & 0o077 == 0
    # the Ego started first; it learns cav1's key from the shared dev trust file
    time.sleep(0.01)
    ego.trust.request_reload()
    assert ego.trust.lookup("cav1", cav.signer.key_id) is not None
    again = auth.identity(config.from_dict({**cfg, "vehicle": {"id": "cav1", "role": "cav"}}))
    assert again.signer.key_id == cav.signer.key_id            # kept across restarts


def test_a_field_vehicle_needs_its_key_files(tmp_path):
    field = {"vehicle": {"id": "cav1", "role": "cav"}, "radar": {"source": "uart", "port": "/dev/null"}}
    with pytest.raises(ConfigError, match="auth.key_file"):
        auth.identity(config.from_dict(field))
    ego = config.merge(field, {"vehicle": {"role": "ego"}, "auth": {"key_file": str(tmp_path / "k")}})
    with pytest.raises(ConfigError, match="auth.trust_file"):
        auth.identity(config.from_dict(ego))
    (tmp_path / "k").write_text("not a key")
    with pytest.raises(ConfigError, match="auth.key_file"):
        auth.identity(config.from_dict(config.merge(field, {"auth": {"key_file": str(tmp_path / "k")}})))
    with pytest.raises(ConfigError, match="auth.key_file"):
        auth.identity(config.from_dict(config.merge(field, {"auth": {"key_file": str(tmp_path / "nope")}})))


def test_over_zenoh_genuine_frames_flow_at_20hz_while_forgeries_are_refused(fleet):
    """A real Node behind a Zenoh peer on 127.0.0.1; a genuine CAV at 20 Hz and an attacker
    (forged, tampered, replayed, stale, future frames) on the same key expression."""
    path, s = fleet
    cfg = config.from_dict({"vehicle": {"id": "ego1", "role": "ego"}, "ego": {"cavs": ["cav1"]}})
    trust = TrustStore(path / "trust.toml")
    verifier = auth.verifier_for(cfg, trust)
    node = Node(cfg, FAKE, default_camera(), 0.7, verifier=verifier)
    ep = f"tcp/127.0.0.1:{free_port()}"
    with Transport(ZenohSection(listen=[ep])) as ego, Transport(ZenohSection(connect=[ep])) as cav, \
            Transport(ZenohSection(connect=[ep])) as bad:
        ego.subscribe(keys.shared("cav1"), "shared", node.on_shared, vehicles=["cav1"],
                      max_payload=node.limits.max_frame_bytes)
        assert cav.wait_for_peers(5) and bad.wait_for_peers(5)
        key = keys.shared("cav1")
        deadline = time.monotonic() + 5
        while node.counters.rx == 0 and time.monotonic() < deadline:   # until the route is up
            cav.put(key, codec.encode(_frame(seq=int(time.time() * 1e6), stamp=time.time()), s["cav1"]))
            time.sleep(0.05)
        rx0, seq = node.counters.rx, int(time.time() * 1e6)
        stop = threading.Event()
        captured: list[bytes] = []

        def attacker() -> None:
            k = 0
            while not stop.is_set():
                now = time.time()
                forged = [codec.encode(_frame(seq=seq + 10**6 + k, stamp=now), Signer("cav1", s["mallory"]._key)),
                          codec.encode(_frame(seq=seq + 10**6 + k, stamp=now)),   # unsigned
                          *captured[-1:]]
                for data in forged:
                    bad.put(key, data)
                if captured:  # a genuine frame made fresh again: new seq and stamp, old signature
                    t = bytearray(captured[-1])
                    at = 18 + 1 + len("cav1")
                    t[at:at + 16] = struct.pack("<Qd", seq + 10**7 + k, time.time())
                    bad.put(key, bytes(t))
                k += 1
                time.sleep(0.005)

        th = threading.Thread(target=attacker, daemon=True)
        th.start()
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 2.0:                       # 2 s of a genuine CAV at 20 Hz
            n += 1
            data = codec.encode(_frame(seq=seq + n, stamp=time.time()), s["cav1"])
            cav.put(key, data)
            captured.append(data)
            time.sleep(0.05)
        # a stale and a future frame, genuinely signed by cav1's key
        cav.put(key, codec.encode(_frame(seq=seq + n + 1, stamp=time.time() - 1.0), s["cav1"]))
        cav.put(key, codec.encode(_frame(seq=seq + n + 2, stamp=time.time() + 1.0), s["cav1"]))
        time.sleep(0.3)
        stop.set()
        th.join(2)
    got = node.counters.rx - rx0
    rej = node.counters.rx_rejected
    print(f"genuine sent {n}, accepted {got}; refused {dict(rej)}")
    assert got >= 0.9 * n and got <= n                         # nothing but the genuine ones got in
    for reason in ("unknown_key", "replay", "bad_signature", "stale", "future"):
        assert rej[reason] >= 1, reason
    assert rej["unknown_key"] >= 2 * n and rej["replay"] + rej["bad_signature"] >= n
    newest = node._inbox["cav1"][-1]
    assert newest.seq <= seq + n                               # the newest frame is a genuine one


def test_mmatch_keys_makes_a_fleet_rotates_and_retires(tmp_path):
    from mmatch.edge.cli import main

    fleet = tmp_path / "fleet"
    assert main(["keys", "--out", str(fleet), "cav1", "ego1"]) == 0
    assert (fleet / "cav1.key").stat().st_mode & 0o077 == 0
    field = {"vehicle": {"id": "ego1", "role": "ego"}, "radar": {"source": "uart", "port": "/dev/null"},
             "auth": {"key_file": str(fleet / "ego1.key"), "trust_file": str(fleet / "trust.toml")}}
    ident = auth.identity(config.from_dict(field))
    assert ident.mode == "files" and ident.trust.vehicles() == ["cav1", "ego1"]
    v = Verifier(ident.trust, ahead_s=0.05, behind_s=0.15, clock=Clock())
    old = Signer.from_file("cav1", fleet / "cav1.key")
    assert main(["keys", "--out", str(fleet), "cav1", "ego1"]) == 0           # idempotent
    assert Signer.from_file("cav1", fleet / "cav1.key").key_id == old.key_id
    assert main(["keys", "--out", str(fleet), "--rotate", "cav1"]) == 0
    new = Signer.from_file("cav1", fleet / "cav1.key")
    assert new.key_id != old.key_id and (fleet / "cav1.key.1.old").exists()
    ident.trust.request_reload()
    assert v.open_frame("cav1", codec.encode(_frame(seq=1), old)).seq == 1   # both trusted meanwhile
    assert v.open_frame("cav1", codec.encode(_frame(seq=2), new)).seq == 2
    assert main(["keys", "--out", str(fleet), "--retire", "cav1"]) == 0
    ident.trust.request_reload()
    with pytest.raises(Rejected, match="unknown_key"):
        v.open_frame("cav1", codec.encode(_frame(seq=3), old))
    assert v.open_frame("cav1", codec.encode(_frame(seq=4), new)).seq == 4
    assert main(["keys", "--out", str(fleet), "bad/id"]) == 2                 # a clear error


def test_a_lagging_ego_still_takes_frames_it_can_pair_with(fleet):
    path, s = fleet
    v = _verifier(path)
    late = codec.encode(_frame(seq=1, stamp=NOW - 0.4), s["cav1"])
    with pytest.raises(Rejected, match="stale"):
        v.open_frame("cav1", late)
    v.pairing_horizon = NOW - 0.45      # the Ego is pairing an own frame captured 0.39 s ago
    assert v.open_frame("cav1", late).seq == 1
    with pytest.raises(Rejected, match="stale"):
        v.open_frame("cav1", codec.encode(_frame(seq=2, stamp=NOW - 0.5), s["cav1"]))


def test_refused_frames_are_never_logged_at_any_size(fleet):
    path, s = fleet

    class Log:
        def __init__(self):
            self.topics = []

        def write(self, topic, data, stamp=None):
            self.topics.append((topic, data))

    clock = Clock()
    cfg = config.from_dict({"vehicle": {"id": "ego1", "role": "ego"}, "ego": {"cavs": ["cav1"]}})
    rec = Log()
    node = Node(cfg, FAKE, default_camera(), 0.7, recorder=rec,
                verifier=auth.verifier_for(cfg, TrustStore(path / "trust.toml"), clock=clock))
    big = _frame(seq=1, stamp=NOW - 5.0, vehicle_points=np.zeros((2000, 5), np.float32),
                 vehicle_index=np.zeros(2000, np.int32))
    for data in (codec.encode(big, s["cav1"]),                                  # stale, 18 KB
                 codec.encode(_frame(seq=2, stamp=NOW - 5.0), s["cav1"]),       # stale, small
                 codec.encode(_frame(seq=3, stamp=NOW + 1.0), s["cav1"]),       # future
                 codec.encode(_frame(seq=4), s["mallory"])):                    # forged
        with pytest.raises(Rejected):
            node.on_shared("cav1", data)
    assert rec.topics == []
    node.on_shared("cav1", codec.encode(_frame(seq=5), s["cav1"]))
    assert rec.topics and all(t.startswith("/shared/rx/cav1") for t, _ in rec.topics)
