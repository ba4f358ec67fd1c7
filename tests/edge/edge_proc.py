"""Helpers to run `mmatch` sub-commands as real processes in tests."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def pinned_time_offset(episode: int = 0) -> float:
    """sim.time_offset_s that starts scenario time now at the beginning of `episode`: the
    simulated vehicles of one test then drive the same worlds on every run (left alone, the
    world is the one of the wall clock's current 10 s slot, a different one each run, and how
    often the Ego is sure enough to fuse depends on the world). Give every vehicle of a test
    the same value."""
    from mmatch.sim.scenario import EPISODE_S

    return round(episode * EPISODE_S - time.time(), 3)


def write_vehicle_cfg(path: Path, *, vid: str, role: str, listen: list[str], connect: list[str],
                      log_dir: Path | None, phase: float = 0.0, cavs: list[str] | None = None,
                      seed: int = 1, mode: str = "easy", extra: str = "",
                      dev_dir: Path | None = None, ego: str = "", time_offset: float = 0.0) -> Path:
    """A simulated vehicle's config; its dev keys live in `dev_dir` (default: beside the file,
    shared by every vehicle of the test); `ego`: more lines of the [ego] table; `time_offset`:
    sim.time_offset_s (see pinned_time_offset)."""
    def arr(xs: list[str]) -> str:
        return "[" + ", ".join(f'"{x}"' for x in xs) + "]"

    text = f"""
[vehicle]
id = "{vid}"
role = "{role}"
[radar]
source = "sim"
[camera]
source = "sim"
[sim]
seed = {seed}
mode = "{mode}"
rate_hz = 20.0
phase_s = {phase}
time_offset_s = {time_offset!r}
[zenoh]
mode = "peer"
listen = {arr(listen)}
connect = {arr(connect)}
[ego]
cavs = {arr(cavs or [])}
{ego}
[loop]
status_interval_s = 1.0
[auth]
keys = "dev"
dev_dir = "{dev_dir or path.parent / 'dev-keys'}"
[log]
dir = "{log_dir or ''}"
chunk_kb = 64
flush_s = 0.2
raw_floor_mb = 0
floor_mb = 0
{extra}
"""
    path.write_text(text)
    return path


def dev_verifier(folder: Path):
    """A Verifier trusting the dev keys of the vehicles a test started from `folder` (the
    trust file is re-read as vehicles add their keys)."""
    from mmatch.edge.auth import TrustStore, Verifier

    deadline = time.monotonic() + 30
    while not (folder / "trust.toml").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return Verifier(TrustStore(folder / "trust.toml"), ahead_s=0.05, behind_s=1.0)


def _service_priority() -> None:
    """The priority systemd/mmatch-edge.service gives the service (Nice=-5), when allowed."""
    try:
        os.nice(-5)
    except OSError:
        pass


def start(args: list[str], log_file: Path, env: dict | None = None, nice: bool = True) -> subprocess.Popen:
    e = dict(os.environ)
    e.update(env or {})
    out = open(log_file, "ab")
    try:
        return subprocess.Popen([sys.executable, "-m", "mmatch.edge.cli", "-v", *args], cwd=REPO, env=e,
                                stdout=out, stderr=subprocess.STDOUT,
                                preexec_fn=_service_priority if nice else None)
    finally:
        out.close()


def mmatch(args: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mmatch.edge.cli", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait(5)
    return proc.returncode


def wait_for(cond, timeout: float, step: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(step)
    return False


def open_fds() -> int:
    """Open file descriptors of this process (sockets, ptys, files)."""
    return len(os.listdir("/proc/self/fd"))
