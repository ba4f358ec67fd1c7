"""Simulator backend: the detections the scene simulator gives a vehicle's camera.

Uses `mmatch.sim.scenario.make_scenario(seed, mode).observe(role, t)` on a frame grid of
`rate_hz` over the shared clock (time.time() by default), so a camera-only test or a bench
can run with no hardware. (The vehicle service pairs its simulated camera with its simulated
radar in edge.sources.sim; this one stands alone.)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from mmatch.drivers.camera.sources.base import CameraSource
from mmatch.types import CameraModel, Detections


class SimCamera(CameraSource):
    """Detections of a simulated vehicle's camera at `rate_hz` on `clock`."""

    name = "sim"

    def __init__(
        self,
        seed: int = 1,
        mode: str = "mixed",
        role: str = "ego",
        rate_hz: float = 20.0,
        clock: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep,
        scenario=None,
    ) -> None:
        if role not in ("ego", "cav"):
            raise ValueError(f"role must be ego or cav, not {role!r}")
        if scenario is None:
            from mmatch.sim.scenario import make_scenario

            scenario = make_scenario(seed, mode)
        self.scenario = scenario
        self.role = role
        self.period = 1.0 / rate_hz
        self.clock, self._sleep = clock, sleep
        self._next_tick: int | None = None
        self._frames = 0

    @property
    def camera(self) -> CameraModel:
        return self.scenario.camera_model(self.role)[0]

    def read(self, timeout: float) -> Detections | None:
        now = self.clock()
        tick = math.floor(now / self.period) + 1 if self._next_tick is None else self._next_tick
        if (
            tick + 1
        ) * self.period < now:  # fell behind: jump to the newest frame, as a camera would
            tick = math.floor(now / self.period)
        t = tick * self.period
        if t - now > timeout:
            self._sleep(max(timeout, 0.0))
            return None
        if t > now:
            self._sleep(t - now)
        obs = self.scenario.observe(self.role, t)
        self._next_tick = tick + 1
        self._frames += 1
        return Detections(
            boxes=np.asarray(obs.boxes, np.float32),
            features=np.asarray(obs.features, np.float32),
            stamp=float(t),
        )

    def counters(self) -> dict[str, int]:
        return {"frames": self._frames}

    def close(self) -> None:
        pass
