"""Package layout only (everything else is in pyproject.toml).

The repository keeps `mmatch/`, `drivers/` and `edge/` side by side (DESIGN.md); the wheel
installs the last two as `mmatch.drivers` and `mmatch.edge`, so nothing generic lands at
the top of site-packages. The fitted models beside the code that loads them (RM-net's ONNX
file and card in `mmatch.models`, the confidence model in `mmatch.ego`, the separation model in
`mmatch.cav`) ship as package data. The data folders `cfg/` (vehicle and Zenoh configs, radar chirp
profiles, an example camera calibration) and `systemd/` (the unit file) ship as package
data under `mmatch.cfg` and `mmatch.systemd` (read with `mmatch.edge.resources`).
"""

from setuptools import find_packages, setup

MAPPED = ("edge", "drivers")
DATA = {"cfg": ["*.toml", "radar/*.cfg", "zenoh/*.json5", "camera/*.toml"],
        "systemd": ["*.service", "*.md"]}

packages = find_packages(include=["mmatch", "mmatch.*"])
package_dir = {}
for top in MAPPED:
    for pkg in find_packages(include=[top, f"{top}.*"]):
        packages.append(f"mmatch.{pkg}")
    package_dir[f"mmatch.{top}"] = top
package_data = {}
for top, patterns in DATA.items():
    packages.append(f"mmatch.{top}")
    package_dir[f"mmatch.{top}"] = top
    package_data[f"mmatch.{top}"] = patterns

package_data["mmatch.models"] = ["*.onnx", "*.md"]
package_data["mmatch.ego"] = ["*.json"]          # the confidence model
package_data["mmatch.cav"] = ["*.json"]          # the learned separation

setup(packages=packages, package_dir=package_dir, package_data=package_data)
