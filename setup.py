"""Package layout only (everything else is in pyproject.toml).

The repository keeps `mmatch/`, `drivers/` and `edge/` side by side (DESIGN.md); the wheel
installs the last two as `mmatch.drivers` and `mmatch.edge`, so nothing generic lands at
the top of site-packages.
"""

from setuptools import find_packages, setup

MAPPED = ("edge", "drivers")

packages = find_packages(include=["mmatch", "mmatch.*"])
package_dir = {}
for top in MAPPED:
    for pkg in find_packages(include=[top, f"{top}.*"]):
        packages.append(f"mmatch.{pkg}")
    package_dir[f"mmatch.{top}"] = top

setup(packages=packages, package_dir=package_dir)
