"""The package: pins agree with requirements.txt, extras are lean, the wheel holds what it should."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _pins(lines: list[str]) -> dict[str, str]:
    out = {}
    for line in lines:
        line = line.split("#", 1)[0].strip()
        if line:
            m = re.fullmatch(r"([A-Za-z0-9_.\-]+)==([^\s;]+)", line)
            assert m, f"not pinned with ==: {line!r}"
            out[m.group(1).lower()] = m.group(2)
    return out


def _project() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["project"]


def test_pyproject_pins_agree_with_requirements():
    req = _pins((REPO / "requirements.txt").read_text().splitlines())
    proj = _project()
    declared = _pins(proj["dependencies"])
    for extra in proj["optional-dependencies"].values():
        declared.update(_pins(extra))
    for name, version in declared.items():
        if name in req:
            assert req[name] == version, f"{name}: pyproject {version}, requirements.txt {req[name]}"
    assert set(_pins(proj["dependencies"])) <= set(req), "CI must install every runtime dependency"


def test_depthai_only_in_the_hardware_extra():
    proj = _project()
    assert not any(d.startswith("depthai") for d in proj["dependencies"])
    assert proj["optional-dependencies"]["hardware"] == ["depthai==3.12.0"]
    assert not any(d.startswith("torch") for d in proj["dependencies"])


def test_licence_and_citation():
    assert (REPO / "LICENSE").read_text().split()[:4] == ["Apache", "License", "Version", "2.0,"]
    assert _project()["license"] == "Apache-2.0"
    cff = (REPO / "CITATION.cff").read_text()
    assert 'title: "Improving Multi-Vehicle Perception Fusion with Millimeter-Wave Radar Assistance"' in cff
    assert "arXiv:2506.00837" in cff


def test_wheel_maps_folders_under_mmatch_and_ships_the_data(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(REPO)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    (wheel,) = tmp_path.glob("mmatch-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/", 1)[0] for n in names}
    assert tops == {"mmatch", "mmatch-0.1.0.dist-info"}, tops
    for must in ("mmatch/edge/cli.py", "mmatch/drivers/ti/reader.py", "mmatch/cfg/vehicle-ego-sim.toml",
                 "mmatch/cfg/vehicle-cav-sim.toml", "mmatch/cfg/radar/xwr68xx_vehicle_100m.cfg",
                 "mmatch/cfg/zenoh/router.json5", "mmatch/cfg/camera/example_calibration.toml",
                 "mmatch/systemd/mmatch-edge.service", "mmatch-0.1.0.dist-info/licenses/LICENSE"):
        assert must in names, must
    meta = zipfile.ZipFile(wheel).read("mmatch-0.1.0.dist-info/METADATA").decode()
    assert "License-Expression: Apache-2.0" in meta
    requires = [line for line in meta.splitlines() if line.startswith("Requires-Dist:")]
    assert any("depthai==3.12.0; extra == \"hardware\"" in line for line in requires)
    assert not any("depthai" in line and "extra" not in line for line in requires)
