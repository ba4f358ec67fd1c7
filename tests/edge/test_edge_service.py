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
    assert "/s" in status and "drops" in status and "DEV KEYS" in status  # simulated: flagged
    report = logreader.LogReport()
    frames = sum(1 for m in logreader.read_messages(tmp_path / "logs", report=report) if m.topic == "/vehicle/frame")
    assert report.truncated == [] and frames > 5  # finished file: summary and footer written


def test_bad_config_is_refused_at_start_naming_the_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[vehicle]\nid = "x"\n[radar]\nbaudrate = "fast"\n')
    res = mmatch(["run", "-c", str(bad)])
    assert res.returncode == 78 and "radar.baudrate" in res.stderr   # EX_CONFIG: systemd does not restart
    res = mmatch(["run", "-c", str(REPO / "cfg" / "vehicle-cav-sim.toml"), "--set", "sim.rate_hz=-5"])
    assert res.returncode == 78 and "sim.rate_hz" in res.stderr


@pytest.mark.parametrize("case, message", [
    ("latin1", "not UTF-8"), ("folder", "is a folder"), ("empty", "empty"), ("comments", "empty"),
    ("missing", "no such file"), ("zenoh_file", "zenoh.config_file"), ("zenoh_dir", "zenoh.config_file"),
    ("field_no_key", "auth.key_file"),
])
def test_each_broken_config_is_a_clear_error_naming_the_path_or_key(tmp_path, case, message):
    path = tmp_path / "v.toml"
    sim = '[vehicle]\nid = "cav1"\nrole = "cav"\n[auth]\ndev_dir = "%s"\n' % (tmp_path / "dev")
    if case == "latin1":
        path.write_bytes('[vehicle]\nid = "véhicule"\n'.encode("latin-1"))
    elif case == "folder":
        path = tmp_path
    elif case == "empty":
        path.write_text("")
    elif case == "comments":
        path.write_text("# nothing but a comment\n")
    elif case == "missing":
        path = tmp_path / "nope.toml"
    elif case == "zenoh_file":
        path.write_text(sim + '[zenoh]\nconfig_file = "%s"\n' % (tmp_path / "gone.json5"))
    elif case == "zenoh_dir":
        path.write_text(sim + '[zenoh]\nconfig_file = "%s"\n' % tmp_path)
    elif case == "field_no_key":
        path.write_text('[vehicle]\nid = "cav1"\n[radar]\nsource = "uart"\nport = "/dev/null"\n')
    res = mmatch(["run", "-c", str(path), "--duration", "5"])
    assert res.returncode == 78, (res.returncode, res.stderr[-1000:])
    assert message in res.stderr and "Traceback" not in res.stderr, res.stderr[-1000:]
    if case not in ("zenoh_file", "zenoh_dir", "field_no_key"):
        assert str(path) in res.stderr


def test_the_recorder_opens_after_zenoh_a_failed_start_leaves_no_log(tmp_path):
    from netutil import free_port

    port = free_port()
    busy = socket.socket()
    busy.bind(("127.0.0.1", port))
    busy.listen()
    try:
        cfg = write_vehicle_cfg(tmp_path / "cav.toml", vid="cav1", role="cav",
                                listen=[f"tcp/127.0.0.1:{port}"], connect=[], log_dir=tmp_path / "logs")
        res = mmatch(["run", "-c", str(cfg), "--duration", "5"])
    finally:
        busy.close()
    assert res.returncode == 2 and "zenoh" in res.stderr, res.stderr[-1000:]
    assert not (tmp_path / "logs").exists()              # no empty log of a run that never started


def test_sighup_reloads_the_trust_file_without_a_restart(tmp_path):
    cfg = write_vehicle_cfg(tmp_path / "ego.toml", vid="ego1", role="ego", listen=[], connect=[],
                            log_dir=None, cavs=["cav1"])
    out = tmp_path / "ego.out"
    proc = start(["run", "-c", str(cfg)], out)
    try:
        assert wait_for(lambda: "loop running" in out.read_text(), 40), out.read_text()[-2000:]
        assert out.read_text().count("trust file") == 1
        proc.send_signal(signal.SIGHUP)
        assert wait_for(lambda: out.read_text().count("trust file") == 2, 10), out.read_text()[-2000:]
        assert proc.poll() is None                           # still running: no restart
        assert stop(proc) == 0
    finally:
        stop(proc, signal.SIGKILL)
