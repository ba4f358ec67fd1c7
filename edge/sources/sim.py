"""Simulated sensors: `mmatch.sim.scenario` played over the shared clock.

Frames come at `sim.rate_hz` on the grid k / rate + `sim.phase_s` of the vehicle's own
clock (time.time() + `sim.clock_offset_s`, its synchronisation error); every process that uses the same seed and mode sees the same world, each
from its own vehicle (`sim.view`). A frame is rendered just ahead of its capture time
and delivered at it, as a sensor delivers what it captured. The camera of the same vehicle
gets the detections of the same observation. With `sim.render_process` (default) a child
process renders (mmatch/sim/renderd.py): like a real sensor, the simulated one then does
not hold the vehicle process's interpreter lock while its frame loop works.
"""

from __future__ import annotations

import logging
import math
import time

from mmatch.edge.config import VehicleConfig
from mmatch.edge.sources.base import CameraSource, RadarSource
from mmatch.edge.transport import KeepNewest
from mmatch.sim.renderd import RenderError, RenderProcess
from mmatch.types import CameraModel, Detections, RadarFrame

log = logging.getLogger(__name__)


def sim_view(cfg: VehicleConfig) -> str:
    if cfg.sim.view != "auto":
        return cfg.sim.view
    return "cav" if cfg.vehicle.role == "cav" else "ego"


class SimRadar(RadarSource):
    """The radar of the simulated vehicle `sim_view(cfg)`."""

    def __init__(self, cfg: VehicleConfig, *, clock=time.time, sleep=time.sleep, **kw) -> None:
        from mmatch.sim.scenario import make_scenario

        self.cfg = cfg
        self.view = sim_view(cfg)
        self.scenario = make_scenario(cfg.sim.seed, cfg.sim.mode, covisible=cfg.sim.covisible)
        self.period = 1.0 / cfg.sim.rate_hz
        self._clock, self._sleep = clock, sleep
        self._next: float | None = None
        self._frame_number = 0
        self.skipped = 0
        self._render_s = 0.015  # running estimate of one observation's render time, s
        self.camera_feed: KeepNewest[Detections] | None = None
        self._closed = False
        self.render_fallbacks = 0
        self._renderer: RenderProcess | None = None
        if cfg.sim.render_process:
            try:
                sim = cfg.sim
                self._renderer = RenderProcess(sim.seed, sim.mode, sim.covisible, self.view)
            except OSError as exc:
                self.render_fallbacks += 1
                log.warning("simulated %s sensor: no render process (%s); rendering in this process",
                            self.view, exc)
        self._warm_up()

    def _warm_up(self) -> None:
        """Draw the current episode's world now (it can take half a second), not in the first read."""
        from mmatch.sim.scenario import EPISODE_S

        t = self._clock() + self.cfg.sim.time_offset_s
        if self._renderer is not None:
            self._render(t, timeout_s=60.0)
        else:
            self.scenario.world(int(t // EPISODE_S))

    def _render(self, t: float, timeout_s: float = 5.0):
        """The observation at scenario time t, from the render process while it answers."""
        if self._renderer is not None:
            try:
                return self._renderer.observe(t, timeout_s)
            except RenderError as exc:
                self.render_fallbacks += 1
                log.warning("simulated %s sensor: %s; rendering in this process from now on",
                            self.view, exc)
                self._renderer.close()
                self._renderer = None
        return self.scenario.observe(self.view, t)

    @property
    def camera(self) -> CameraModel:
        return self.scenario.camera_model(self.view)[0]

    @property
    def radar_height(self) -> float:
        return self.scenario.mounts[self.view].radar_height

    def _grid_after(self, t: float) -> float:
        k = math.ceil((t - self.cfg.sim.phase_s) / self.period - 1e-9)
        return k * self.period + self.cfg.sim.phase_s

    def _own_clock(self) -> float:
        """This vehicle's clock: true (shared) time + its synchronisation error."""
        return self._clock() + self.cfg.sim.clock_offset_s

    def read(self, timeout: float) -> RadarFrame | None:
        now = self._own_clock()
        if self._next is None or self._next < now - self.period:
            if self._next is not None:
                self.skipped += 1
            self._next = self._grid_after(now)
        t = self._next
        # render just in time (not while the loop is still busy with the previous frame)
        lead = 1.5 * self._render_s + 0.003
        if t - lead - now > timeout:
            self._sleep(timeout)
            return None
        if t - lead - now > 0:
            self._sleep(t - lead - now)
        r0 = time.perf_counter()
        # captured at true time t - clock_offset, stamped on the vehicle's own clock
        obs = self._render(t - self.cfg.sim.clock_offset_s + self.cfg.sim.time_offset_s)
        self._render_s = 0.8 * self._render_s + 0.2 * (time.perf_counter() - r0)
        wait = t - self._own_clock()
        if wait > 0:
            self._sleep(wait)
        self._next = t + self.period
        self._frame_number += 1
        if self.camera_feed is not None:
            self.camera_feed.put(Detections(boxes=obs.boxes, features=obs.features, stamp=t))
        return RadarFrame(points=obs.points, stamp=t, frame_number=self._frame_number,
                          host_time=self._own_clock())

    def counters(self) -> dict[str, int]:
        return {"frames": self._frame_number, "late_skips": self.skipped,
                "render_fallbacks": self.render_fallbacks}

    def close(self) -> None:
        self._closed = True
        if self._renderer is not None:
            self._renderer.close()
        self.scenario.close()


class SimCamera(CameraSource):
    """The camera of the simulated vehicle: the detections of the radar's observation.

    Pass the SimRadar as `radar=`; alone it renders its own observations at the same grid.
    """

    def __init__(self, cfg: VehicleConfig, *, radar: RadarSource | None = None, **kw) -> None:
        self._own_radar: SimRadar | None = None
        if isinstance(radar, SimRadar):
            self._radar = radar
        else:
            self._own_radar = self._radar = SimRadar(cfg, **kw)
        self._feed: KeepNewest[Detections] = KeepNewest(4)
        self._radar.camera_feed = self._feed

    @property
    def camera(self) -> CameraModel:
        return self._radar.camera

    def read(self, timeout: float) -> Detections | None:
        if self._own_radar is not None:
            self._own_radar.read(timeout)
        return self._feed.get(timeout)

    def close(self) -> None:
        self._feed.close()
