"""Every fitted model the runtime loads ships in the wheel (package data of setup.py)."""

from __future__ import annotations

import ast
import fnmatch
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_model_file_is_package_data():
    text = (ROOT / "setup.py").read_text()
    data = dict(re.findall(r'package_data\["([\w.]+)"\] = (\[[^\]]*\])', text))
    models = [p for ext in ("*.json", "*.onnx") for p in (ROOT / "mmatch").rglob(ext)]
    assert models
    for p in models:
        pkg = "mmatch." + ".".join(p.relative_to(ROOT / "mmatch").parent.parts) if p.parent != ROOT / "mmatch" \
            else "mmatch"
        patterns = ast.literal_eval(data.get(pkg, "[]"))
        assert any(fnmatch.fnmatch(p.name, pat) for pat in patterns), f"{p} is not package data of {pkg}"
