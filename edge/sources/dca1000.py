"""AWR2243 + DCA1000EVM: raw ADC frames over UDP -> our DSP -> points.

At open the FPGA is set up over its command port (connect, version, FPGA and packet
config) and recording starts; a thread reassembles frames from the data port into a
keep-newest queue. `read` hands each raw frame to `raw_sink` (the field log's
/raw/dca1000), skips and counts frames with missing packets, and runs the DSP configured
from the same .cfg as the UART path. Any socket or FPGA error is a DeviceError: the loop
closes, waits and starts again.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from mmatch.edge import logschema
from mmatch.edge.config import VehicleConfig
from mmatch.edge.sources.base import RadarSource
from mmatch.edge.transport import KeepNewest
from mmatch.errors import DeviceError
from mmatch.types import RadarFrame

log = logging.getLogger(__name__)


class Dca1000Radar(RadarSource):
    raw_topic = logschema.RAW_DCA

    def __init__(self, cfg: VehicleConfig, **kw: Any) -> None:
        from mmatch.drivers.dca1000.dsp import make_dsp
        from mmatch.drivers.ti.cfg import load_cfg

        self.cfg = cfg
        self.radar_cfg = load_cfg(cfg.radar.cfg)
        self.geom, self.dsp = make_dsp(self.radar_cfg, cfg.radar.dca_layout)
        self._queue: KeepNewest[Any] = KeepNewest(max(2, cfg.loop.queue_size))
        self._receiver: Any = None
        self._control: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.frames = 0
        self.incomplete = 0
        self.radar_height = cfg.radar.height_m

    def open(self) -> None:
        from mmatch.drivers.dca1000.assembler import FrameAssembler
        from mmatch.drivers.dca1000.control import Dca1000Control
        from mmatch.drivers.dca1000.receiver import DataReceiver

        r = self.cfg.radar
        self._stop.clear()
        self._error = None
        self._receiver = DataReceiver(FrameAssembler(self.geom.frame_bytes, policy="flag"),
                                      host=r.dca_host, port=r.dca_data_port)
        try:
            self._control = Dca1000Control(host=r.dca_fpga_host, port=r.dca_config_port,
                                           local=(r.dca_host, r.dca_local_config_port))
            self._control.setup()
            self._control.start_record()
        except Exception:
            self.close()
            raise
        self._thread = threading.Thread(target=self._receive, name="dca1000-rx", daemon=True)
        self._thread.start()
        log.info("DCA1000 recording: %d-byte frames on %s:%d", self.geom.frame_bytes, r.dca_host, r.dca_data_port)

    def _receive(self) -> None:
        try:
            while not self._stop.is_set() and self._receiver is not None:
                for frame in self._receiver.frames(idle_timeout_s=0.2, flush=False):
                    self._queue.put((frame, time.time()))
                    if self._stop.is_set():
                        break
        except Exception as exc:  # reported to the loop by the next read
            if not self._stop.is_set():
                self._error = exc

    def read(self, timeout: float) -> RadarFrame | None:
        from mmatch.drivers.dca1000.layout import raw_to_cube

        if self._error is not None:
            err, self._error = self._error, None
            raise DeviceError(f"DCA1000 receiver: {err}") from err
        if self._receiver is None:
            raise DeviceError("DCA1000 source is not open")
        item = self._queue.get(timeout)
        if item is None:
            return None
        frame, t_rx = item
        if self.raw_sink is not None:
            self.raw_sink(frame.data.tobytes())
        if not frame.complete:
            self.incomplete += 1
            log.debug("DCA1000 frame %d: %d bytes missing; skipped", frame.index, frame.missing_bytes)
            return None
        res = self.dsp.process(raw_to_cube(frame.data, self.geom))
        self.frames += 1
        return RadarFrame(points=res.points, stamp=t_rx, frame_number=int(frame.index), host_time=t_rx)

    def counters(self) -> dict[str, int]:
        out = {"frames": self.frames, "incomplete": self.incomplete, "queue_dropped": self._queue.dropped}
        if self._receiver is not None:
            st = self._receiver.stats
            for k, v in st.as_dict().items():
                out[f"stream_{k}"] = int(v)
        return out

    def close(self) -> None:
        self._stop.set()
        control, self._control = self._control, None
        if control is not None:
            try:
                control.stop_record()
            except Exception as exc:
                log.debug("DCA1000 stop: %s", exc)
            control.close()
        receiver, self._receiver = self._receiver, None
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if receiver is not None:
            receiver.close()
