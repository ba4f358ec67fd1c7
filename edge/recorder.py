"""Field logging to MCAP: chunked, rotated, and careful with the disk.

* Chunked writing straight to the file descriptor (no user-space buffer): a chunk reaches
  the OS as soon as it closes, and chunks close when full (`chunk_kb`) or at least every
  `flush_s` seconds. A process killed with SIGKILL leaves a file that reads up to its last
  complete chunk (`edge.logreader`).
* Rotation by size (`rotate_mb`) and age (`rotate_s`); each file is a complete MCAP with
  the effective config as metadata.
* A free-disk floor: below `raw_floor_mb` raw data (UART bytes, DCA1000 frames) stops;
  below `floor_mb` everything stops. Both resume when space returns. Dropped writes are
  counted by reason.
* Log times come from a strictly increasing ns clock shared by every topic, so file order
  is the order of `write` calls across threads.
"""

from __future__ import annotations

import collections
import json
import logging
import os
import shutil
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from edge import logschema
from edge.config import LogSection
from mmatch.errors import DeviceError

log = logging.getLogger(__name__)

MB = 1024 * 1024


class _RawFile:
    """An unbuffered file whose write never returns short; tell() tracks the size.

    Deliberately not an io.RawIOBase: mcap's Writer would wrap that in a BufferedWriter.
    """

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o640)
        self._pos = 0

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            done += os.write(self._fd, view[done:])
        self._pos += done
        return done

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class Recorder:
    """Thread-safe MCAP writer with rotation and a disk floor. A context manager.

    `write(topic, data)` takes bytes (raw/binary topics) or a dict (JSON topics) and returns
    True when the message was written. `stamp` (s) becomes the MCAP publish time.
    """

    def __init__(self, cfg: LogSection, *, prefix: str = "mmatch", config_text: str = "",
                 free_bytes: Callable[[Path], int] | None = None,
                 clock_ns: Callable[[], int] = time.time_ns) -> None:
        if not cfg.dir:
            raise DeviceError("recorder: log.dir is empty")
        self.cfg = cfg
        self.dir = Path(cfg.dir)
        self.prefix = prefix
        self.config_text = config_text
        self._free_bytes = free_bytes or (lambda p: shutil.disk_usage(p).free)
        self._clock_ns = clock_ns
        self._lock = threading.Lock()
        self._writer: Any = None
        self._file: _RawFile | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._seq: dict[int, int] = collections.defaultdict(int)
        self._last_ns = 0
        self._opened_at = 0.0
        self._last_flush = 0.0
        self._last_disk_check = -1e9
        self._free = 1 << 62
        self._metadata: dict[str, dict[str, str]] = {}
        self.files: list[Path] = []
        self.written = 0
        self.dropped: dict[str, int] = collections.Counter()
        self.raw_stopped = False
        self.all_stopped = False
        self._closed = False

    # ------------------------------------------------------------------ files
    def open(self) -> Recorder:
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DeviceError(f"recorder: cannot create log dir {self.dir}: {exc}") from exc
        if self.config_text:
            stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
            (self.dir / f"{self.prefix}-{stamp}.config.toml").write_text(self.config_text)
        with self._lock:
            self._check_disk(force=True)
            if not self.all_stopped:
                self._start_file()
        return self

    def __enter__(self) -> Recorder:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _new_path(self) -> Path:
        """<prefix>-<UTC yyyymmdd-hhmmss-mmm>-<n>.mcap: names sort in time order; n counts the
        files of one run (0000 starts a run)."""
        now = time.time()
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(now)) + f"-{int(now * 1000) % 1000:03d}"
        n = len(self.files)
        while True:
            path = self.dir / f"{self.prefix}-{stamp}-{n:04d}.mcap"
            if not path.exists():
                return path
            n += 1

    def _start_file(self) -> None:
        from mcap.writer import CompressionType, Writer

        path = self._new_path()
        self._file = _RawFile(path)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}[self.cfg.compression]
        self._writer = Writer(self._file, chunk_size=int(self.cfg.chunk_kb * 1024), compression=comp)
        self._writer.start(profile="", library="mmatch-edge")
        if self.config_text:
            self._writer.add_metadata("config", {"toml": self.config_text})
        for name, meta in self._metadata.items():
            self._writer.add_metadata(name, meta)
        self._channels.clear()
        self._schemas.clear()
        self._opened_at = time.monotonic()
        self._last_flush = self._opened_at
        self.files.append(path)
        log.info("recording to %s", path)

    def _finish_file(self) -> None:
        if self._writer is None:
            return
        try:
            self._writer.finish()
        finally:
            assert self._file is not None
            self._file.close()
            self._writer, self._file = None, None

    def close(self) -> None:
        """Finish the current file (summary + footer); safe twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._finish_file()

    def set_metadata(self, name: str, meta: dict[str, str]) -> None:
        """A metadata record written now and at the start of every later file."""
        with self._lock:
            self._metadata[name] = dict(meta)
            if self._writer is not None:
                self._writer.add_metadata(name, dict(meta))

    # ------------------------------------------------------------------ disk
    def _check_disk(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_disk_check < 1.0:
            return
        self._last_disk_check = now
        try:
            self._free = int(self._free_bytes(self.dir))
        except OSError as exc:
            log.warning("recorder: cannot read free disk space: %s", exc)
            return
        raw_stop = self._free < self.cfg.raw_floor_mb * MB
        all_stop = self._free < self.cfg.floor_mb * MB
        if raw_stop != self.raw_stopped:
            log.warning("recorder: raw data %s (free %.0f MB, floor %.0f MB)",
                        "stopped" if raw_stop else "resumed", self._free / MB, self.cfg.raw_floor_mb)
        if all_stop != self.all_stopped:
            log.warning("recorder: all logging %s (free %.0f MB, floor %.0f MB)",
                        "stopped" if all_stop else "resumed", self._free / MB, self.cfg.floor_mb)
            if all_stop:
                self._finish_file()
        self.raw_stopped, self.all_stopped = raw_stop, all_stop

    # ------------------------------------------------------------------ writing
    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        name, enc, data, msg_enc = logschema.schema_for(topic)
        sid = 0
        if enc:
            sid = self._schemas.get(name, 0)
            if not sid:
                sid = self._writer.register_schema(name=name, encoding=enc, data=data)
                self._schemas[name] = sid
        cid = self._writer.register_channel(topic=topic, message_encoding=msg_enc, schema_id=sid)
        self._channels[topic] = cid
        return cid

    def now_ns(self) -> int:
        """The next log time: wall clock ns, strictly increasing."""
        with self._lock:
            return self._next_ns()

    def _next_ns(self) -> int:
        t = max(self._clock_ns(), self._last_ns + 1)
        self._last_ns = t
        return t

    def write(self, topic: str, data: bytes | dict, stamp: float | None = None) -> bool:
        """Log one message; False (and counted) when the disk floor or a close stops it."""
        payload = data if isinstance(data, (bytes, bytearray, memoryview)) else \
            json.dumps(data, separators=(",", ":")).encode()
        with self._lock:
            if self._closed:
                self.dropped["closed"] += 1
                return False
            self._check_disk()
            if self.all_stopped:
                self.dropped["disk_floor"] += 1
                return False
            if self.raw_stopped and logschema.is_raw(topic):
                self.dropped["raw_disk_floor"] += 1
                return False
            if self._writer is None:
                self._start_file()
            self._maybe_rotate()
            cid = self._channel(topic)
            log_ns = self._next_ns()
            pub_ns = log_ns if stamp is None else max(int(round(stamp * 1e9)), 0)
            self._writer.add_message(channel_id=cid, log_time=log_ns, publish_time=pub_ns,
                                     data=bytes(payload), sequence=self._seq[cid])
            self._seq[cid] += 1
            self.written += 1
            now = time.monotonic()
            if now - self._last_flush >= self.cfg.flush_s:
                self._writer.flush()
                self._last_flush = now
        return True

    def _maybe_rotate(self) -> None:
        assert self._file is not None
        age = time.monotonic() - self._opened_at
        if self._file.tell() >= self.cfg.rotate_mb * MB or age >= self.cfg.rotate_s:
            self._finish_file()
            self._start_file()

    def tick(self) -> None:
        """Close the open chunk when `flush_s` has passed (call periodically when idle)."""
        with self._lock:
            if self._writer is not None and time.monotonic() - self._last_flush >= self.cfg.flush_s:
                self._writer.flush()
                self._last_flush = time.monotonic()

    def stats(self) -> dict[str, Any]:
        with self._lock:
            return {"written": self.written, "files": len(self.files), "dropped": dict(self.dropped),
                    "raw_stopped": self.raw_stopped, "all_stopped": self.all_stopped,
                    "free_mb": round(self._free / MB, 1)}
