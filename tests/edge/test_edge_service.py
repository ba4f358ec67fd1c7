"""`mmatch run` as systemd runs it: notify protocol, watchdog, status, clean stop on SIGTERM
and SIGINT (finished MCAP), and a bad config refused at start naming the key."""

from __future__ import annotations

import signal
import socket

import pytest
from edge_proc import REPO, mmatch, start, stop, wait_for, write_vehicle_cfg

from mmatch.edge import logreader


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_notify_watchdog_status_and_clean_stop(tmp_path, sig):
    sock_path = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(sock_path)
    srv.settimeout(0.2)
    cfg = write_vehicle_cfg(tmp_path / "cav.toml", vid="cav9", role="cav", listen=[], connect=[],
                            log_dir=tmp_path / "logs")
    proc = start(["run", "-c", str(cfg)], tmp_path / "out.txt",
                 env={"NOTIFY_SOCKET": sock_path, "WATCHDOG_USEC": "400000"}, nice=False)
    got: list[str] = []

    def drain() -> bool:
        try:
            while True:
                got.append(srv.recv(4096).decode())
        except (TimeoutError, socket.timeout):
            pass
        return any(m.startswith("READY=1") for m in got) and got.count("WATCHDOG=1") >= 3 and \
            any(m.startswith("STATUS=radar") for m in got)

    try:
        assert wait_for(drain, 40, step=0.01), (got, (tmp_path / "out.txt").read_text()[-3000:])
        rc = stop(proc, sig)
    finally:
        stop(proc, signal.SIGKILL)
        srv.close()
    assert rc == 0, (tmp_path / "out.txt").read_text()[-3000:]
    status = next(m for m in got if m.startswith("STATUS=radar"))
    assert "/s" in status and "drops" in status
    report = logreader.LogReport()
    frames = sum(1 for m in logreader.read_messages(tmp_path / "logs", report=report) if m.topic == "/vehicle/frame")
    assert report.truncated == [] and frames > 5  # finished file: summary and footer written


def test_bad_config_is_refused_at_start_naming_the_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[vehicle]\nid = "x"\n[radar]\nbaudrate = "fast"\n')
    res = mmatch(["run", "-c", str(bad)])
    assert res.returncode == 2 and "radar.baudrate" in res.stderr
    res = mmatch(["run", "-c", str(REPO / "cfg" / "vehicle-cav-sim.toml"), "--set", "sim.rate_hz=-5"])
    assert res.returncode == 2 and "sim.rate_hz" in res.stderr
