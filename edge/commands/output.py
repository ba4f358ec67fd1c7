"""Files the `mmatch` sub-commands write."""

from __future__ import annotations

import json
from pathlib import Path


def write_json(path: str | Path, data: object, indent: int = 2) -> Path:
    """`data` as JSON at `path` (its folder made when missing); says so on stdout; returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=indent))
    print(f"wrote {out}")
    return out
