"""`mmatch router` (the Python binding's router mode) carries samples between two clients,
each sample with its encoding; SIGTERM stops it cleanly."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

from mmatch.edge import keys
from mmatch.edge.config import ZenohSection
from mmatch.edge.transport import ENCODINGS, Transport
from netutil import free_port


def test_router_relays_between_clients_with_encodings():
    ep = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "mmatch.edge.cli", "router", "--listen", ep],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert f"listening on {ep}" in proc.stdout.readline()
        got: dict[str, tuple[str, bytes]] = {}
        done = threading.Event()

        def on_sample(sample) -> None:  # noqa: ANN001
            got[str(sample.key_expr).rsplit("/", 1)[1]] = (str(sample.encoding), sample.payload.to_bytes())
            if len(got) == 3:
                done.set()

        with Transport(ZenohSection(mode="client", connect=[ep])) as ego, \
                Transport(ZenohSection(mode="client", connect=[ep])) as cav:
            sub = ego.session.declare_subscriber("mmatch/v1/**", on_sample)
            assert cav.wait_for_peers(5.0)
            deadline = time.monotonic() + 10
            while not done.is_set() and time.monotonic() < deadline:
                cav.put(keys.shared("cav1"), b"MMSF...")
                cav.put(keys.fused("cav1"), json.dumps({"seq": 1}).encode())
                cav.put(keys.health("cav1"), b"{}")
                done.wait(0.1)
            sub.undeclare()
        assert done.is_set(), got
        assert got["shared"] == ("application/vnd.mmatch.shared-frame", b"MMSF...")
        assert got["fused"][0] == got["health"][0] == "application/vnd.mmatch.signed-message" == ENCODINGS["fused"]
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=15)
        assert proc.returncode == 0, err
        assert "zenoh router stopped" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_router_refuses_a_bad_endpoint():
    r = subprocess.run([sys.executable, "-m", "mmatch.edge.cli", "router", "--listen", "7447"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "'7447' is not an endpoint" in r.stderr
