"""The unit file: notify + watchdog + restart, dedicated user in dialout, hardening, verified."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "systemd" / "mmatch-edge.service"


def _unit() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    section = ""
    for line in UNIT.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        out.setdefault(f"{section}.{key}", []).append(value)
    return out


def test_unit_has_the_required_settings():
    u = _unit()
    one = {k: v[-1] for k, v in u.items()}
    assert one["Service.Type"] == "notify"
    assert int(one["Service.WatchdogSec"]) > 0
    assert one["Service.Restart"] == "on-failure"
    assert one["Service.User"] == "mmatch" and "dialout" in one["Service.SupplementaryGroups"].split()
    assert one["Service.ExecStart"].split()[1:] == ["run", "--config", "/etc/mmatch/vehicle.toml"]
    # write access only to its log dir
    assert one["Service.ProtectSystem"] == "strict" and one["Service.LogsDirectory"] == "mmatch"
    assert "ReadWritePaths" not in " ".join(u)
    for key in ("NoNewPrivileges", "ProtectHome", "PrivateTmp", "ProtectKernelTunables",
                "ProtectKernelModules", "ProtectControlGroups", "RestrictSUIDSGID", "LockPersonality"):
        assert one[f"Service.{key}"] == "yes", key
    assert one["Service.CapabilityBoundingSet"] == ""
    assert one["Service.DevicePolicy"] == "closed"
    assert any("ttyUSB" in d for d in u["Service.DeviceAllow"])


def test_a_config_error_is_not_restarted_memory_is_bounded_and_stop_outlasts_the_recorder():
    from mmatch.edge.commands.run import EXIT_CONFIG
    from mmatch.edge.recorder import CLOSE_TIMEOUT_S

    one = {k: v[-1] for k, v in _unit().items()}
    assert str(EXIT_CONFIG) in one["Service.RestartPreventExitStatus"].split()
    assert one["Service.MemoryMax"].endswith(("M", "G")) and "Service.MemoryHigh" in one
    # SIGTERM -> reader joins (5 s) + the recorder's close + Zenoh's close, before SIGKILL
    assert int(one["Service.TimeoutStopSec"]) >= CLOSE_TIMEOUT_S + 5 + 5


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verify(tmp_path):
    # verify checks that ExecStart exists: point it at this checkout's entry point
    exe = Path(sys.executable).parent / "mmatch"
    if not exe.exists():
        pytest.skip("no mmatch entry point in this environment")
    unit = tmp_path / "mmatch-edge.service"
    unit.write_text(UNIT.read_text().replace("/opt/mmatch/.venv/bin/mmatch", str(exe)))
    res = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "mmatch-edge.service" not in res.stderr, res.stderr  # no warnings about our unit


def test_readme_install_section_exists():
    text = (REPO / "systemd" / "README.md").read_text()
    assert "useradd --system" in text and "dialout" in text and "systemctl enable --now mmatch-edge" in text


