"""A camera that may disappear must never stop the radar path.

`ResilientCamera(factory)` runs a camera source on its own thread: it opens it, reads it,
and when it fails (`DeviceError`, or anything unexpected) reports it (a WARNING log, then
rate-limited), closes it, waits with exponential backoff (`backoff_s` doubling up to
`max_backoff_s`, reset after a good frame) and opens a fresh one. The caller (the radar loop)
only ever sees `read(timeout)` / `latest(max_age)`, which return detections or None and never
raise. A `ConfigError` (wrong model or calibration) is not retried: the state becomes
"failed" and `last_error` says why. Skipped frames (wrong size/type) are counted by the
source and reported in `counters()`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from mmatch.drivers.camera.errors import EndOfStream
from mmatch.drivers.camera.sources.base import CameraSource
from mmatch.errors import ConfigError, MMatchError
from mmatch.types import CameraModel, Detections

log = logging.getLogger(__name__)


class ResilientCamera:
    """Keeps the newest detections of a camera that is reopened whenever it fails.

    factory: builds a fresh, unopened CameraSource (called again after each failure).
    camera: the CameraModel to report before the first successful open (optional).
    """

    def __init__(
        self,
        factory: Callable[[], CameraSource],
        *,
        backoff_s: float = 0.5,
        max_backoff_s: float = 10.0,
        read_timeout_s: float = 0.2,
        camera: CameraModel | None = None,
        name: str = "camera",
        report_every_s: float = 30.0,
    ) -> None:
        self._factory = factory
        self.backoff_s, self.max_backoff_s = backoff_s, max_backoff_s
        self.read_timeout_s = read_timeout_s
        self.name = name
        self.report_every_s = report_every_s
        self._camera = camera
        self._cond = threading.Condition()
        self._latest: Detections | None = None
        self._seq = 0  # detections received so far
        self._read_seq = 0  # last one handed out by read()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.state = "idle"  # idle | running | reconnecting | finished | failed | closed
        self.last_error = ""
        self._counts = {"opens": 0, "failures": 0, "frames": 0, "none": 0}
        self._source_counters: dict[str, int] = {}
        self._last_report = -1e9

    # ---- lifecycle ------------------------------------------------------------------------
    def start(self) -> ResilientCamera:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"{self.name}-reader", daemon=True
            )
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the reader thread and close the source; safe twice."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        t, self._thread = self._thread, None
        if t is not None:
            t.join(timeout=5.0)
        if self.state not in ("finished", "failed"):
            self.state = "closed"

    def __enter__(self) -> ResilientCamera:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- what the radar loop calls --------------------------------------------------------
    @property
    def camera(self) -> CameraModel | None:
        return self._camera

    def read(self, timeout: float) -> Detections | None:
        """Detections newer than the last ones read, waiting up to `timeout` s; None otherwise.
        Never raises."""
        deadline = time.monotonic() + max(timeout, 0.0)
        with self._cond:
            while (
                self._seq == self._read_seq
                and not self._stop.is_set()
                and self.state not in ("finished", "failed")
            ):
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            if self._seq == self._read_seq:
                return None
            self._read_seq = self._seq
            return self._latest

    def latest(self, max_age_s: float | None = None, now: float | None = None) -> Detections | None:
        """The newest detections (None if none, or older than `max_age_s` by their stamp on the
        shared clock `now`, default time.time()). Never raises, never blocks."""
        with self._cond:
            det = self._latest
        if det is None or max_age_s is None:
            return det
        now = time.time() if now is None else now
        return det if abs(now - det.stamp) <= max_age_s else None

    def counters(self) -> dict[str, int]:
        out = dict(self._counts)
        out.update({f"source_{k}": v for k, v in self._source_counters.items()})
        return out

    # ---- the reader thread ----------------------------------------------------------------
    def _report(self, msg: str, *args: object) -> None:
        now = time.monotonic()
        if now - self._last_report >= self.report_every_s or self._counts["failures"] <= 1:
            log.warning(msg, *args)
            self._last_report = now
        else:
            log.debug(msg, *args)

    def _run(self) -> None:
        delay = self.backoff_s
        while not self._stop.is_set():
            source = None
            try:
                source = self._factory()
                source.open()
                self._counts["opens"] += 1
                try:
                    self._camera = source.camera
                except Exception as exc:  # a camera model we cannot read is not fatal to reading
                    log.debug("%s: no camera model yet: %s", self.name, exc)
                self.state = "running"
                if self._counts["opens"] > 1:
                    log.warning("%s: back after %d failure(s)", self.name, self._counts["failures"])
                while not self._stop.is_set():
                    det = source.read(self.read_timeout_s)
                    self._source_counters = source.counters()
                    if det is None:
                        self._counts["none"] += 1
                        continue
                    delay = self.backoff_s
                    with self._cond:
                        self._latest = det
                        self._seq += 1
                        self._counts["frames"] += 1
                        self._cond.notify_all()
            except EndOfStream as exc:
                log.info("%s: %s", self.name, exc)
                self.state = "finished"
                with self._cond:
                    self._cond.notify_all()
                return
            except (
                ConfigError
            ) as exc:  # a wrong model/calibration will not fix itself: stop, say why
                self._counts["failures"] += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
                self.state = "failed"
                log.error("%s: giving up: %s", self.name, self.last_error)
                with self._cond:
                    self._cond.notify_all()
                return
            except Exception as exc:  # DeviceError or anything else: report, back off, retry
                self._counts["failures"] += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
                self.state = "reconnecting"
                kind = "failed" if isinstance(exc, MMatchError) else "failed unexpectedly"
                self._report(
                    "%s %s (%s); retrying in %.2f s", self.name, kind, self.last_error, delay
                )
            finally:
                if source is not None:
                    try:
                        source.close()
                    except Exception as exc:
                        log.debug("%s: close failed: %s", self.name, exc)
            if self._stop.wait(delay):
                break
            delay = min(delay * 2, self.max_backoff_s)
