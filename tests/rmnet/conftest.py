"""RM-net tests: torch is needed only to train and export; CI installs it (requirements-train.txt)."""

from __future__ import annotations

import importlib.util
import os

import numpy as np
import pytest

from mmatch.shared import SharedFrame


def require_torch() -> None:
    """Skip without torch on a developer machine; fail in CI, which must run these tests."""
    if importlib.util.find_spec("torch") is None or importlib.util.find_spec("onnxscript") is None:
        if os.environ.get("CI"):
            pytest.fail("torch/onnxscript missing in CI: `make test` installs requirements-train.txt")
        pytest.skip("torch not installed (pip install -r requirements-train.txt)")


def make_frame(centres, sender: str = "v", features=None, seed: int = 0, velocity=(0.0, 10.0)) -> SharedFrame:
    """A shared frame with one vehicle per centre (x, y in m), 4 radar points each, random descriptors."""
    rng = np.random.default_rng(seed)
    c = np.asarray(centres, np.float32).reshape(-1, 2)
    V = len(c)
    pts = np.zeros((4 * V, 5), np.float32)
    pts[:, :2] = np.repeat(c, 4, 0) + rng.normal(0, 0.3, (4 * V, 2))
    pts[:, 3] = -5.0
    pts[:, 4] = 15.0
    if features is None:
        features = rng.random((V, 32)).astype(np.float32)
    boxes = np.tile(np.array([[100, 100, 200, 180, 0.9, 20.0]], np.float32), (V, 1))
    boxes[:, 5] = np.linalg.norm(c, axis=1)
    return SharedFrame(sender=sender, seq=0, stamp=0.0, radar_height=0.6,
                       ego_velocity=np.asarray(velocity, float), vehicle_points=pts,
                       vehicle_index=np.repeat(np.arange(V), 4).astype(np.int32), vehicle_boxes=boxes,
                       vehicle_box_index=np.arange(V, dtype=np.int32), vehicle_centers=c,
                       vehicle_features=np.asarray(features, np.float32),
                       background=rng.uniform(-30, 30, (60, 3)).astype(np.float32))
