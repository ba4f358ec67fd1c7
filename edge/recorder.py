"""Field logging to MCAP: chunked, rotated, and careful with the disk.

* Chunked writing straight to the file descriptor (no user-space buffer): a chunk reaches
  the OS as soon as it closes, and chunks close when full (`chunk_kb`) or at least every
  `flush_s` seconds. A process killed with SIGKILL leaves a file that reads up to its last
  complete chunk (`mmatch.edge.logreader`).
* Rotation by size (`rotate_mb`) and age (`rotate_s`); each file is a complete MCAP with
  the effective config as metadata.
* A free-disk floor: below `raw_floor_mb` raw data (UART bytes, DCA1000 frames) stops;
  below `floor_mb` everything stops. Both resume when space returns. Dropped writes are
  counted by reason.
* Log times come from a strictly increasing ns clock shared by every topic, so file order
  is the order of `write` calls across threads. A writer thread does the file work.
* A full or failing disk never stops the caller: the recorder (also at start) gives up the
  file, drops what comes (counted as "disk_error") without touching the disk, and tries one
  new file after a back-off (1 s doubling to `log.retry_s`); a file that failed before its
  first message is removed, so a fault makes no new files while it lasts. One error is logged
  when a fault starts and at most one per `log.error_interval_s` while it lasts; `stats()`
  says "failing" with the error, and recording resumes by itself when the disk is back.
"""

from __future__ import annotations

import collections
import json
import logging
import os
import queue
import shutil
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mmatch.edge import logschema
from mmatch.edge.config import LogSection
from mmatch.errors import DeviceError

log = logging.getLogger(__name__)

MB = 1024 * 1024
#: at most this long to write what is queued and finish the file on close, s
#: (systemd/mmatch-edge.service's TimeoutStopSec is longer)
CLOSE_TIMEOUT_S = 30.0


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


def _encode(data: bytes | bytearray | memoryview | dict) -> bytes:
    """Record bytes: bytes as they are, a dict as compact JSON."""
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    return json.dumps(data, separators=(",", ":")).encode()


class Recorder:
    """Thread-safe MCAP writer with rotation and a disk floor. A context manager.

    `write(topic, data)` takes bytes (raw/binary topics) or a dict (JSON topics), gives the
    message its log time and queues it; a writer thread does the file work, so a slow disk
    never stalls the sensor threads or the loop (a full queue drops and counts). It returns
    False when the disk floor, a full queue or a close refused the message. `stamp` (s)
    becomes the MCAP publish time.
    """

    def __init__(self, cfg: LogSection, *, prefix: str = "mmatch", config_text: str = "",
                 free_bytes: Callable[[Path], int] | None = None,
                 clock_ns: Callable[[], int] = time.time_ns, queue_size: int = 10000,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        if not cfg.dir:
            raise DeviceError("recorder: log.dir is empty")
        self.cfg = cfg
        self.dir = Path(cfg.dir)
        self.prefix = prefix
        self.config_text = config_text
        self._free_bytes = free_bytes or (lambda p: shutil.disk_usage(p).free)
        self._clock_ns = clock_ns
        self._monotonic = monotonic            # s: rotation age, disk checks, fault back-off
        self._lock = threading.Lock()          # front: log times, floors, queue order
        self._queue: queue.Queue = queue.Queue(queue_size)
        self._thread: threading.Thread | None = None
        # writer-thread state
        self._writer: Any = None
        self._file: _RawFile | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._seq: dict[int, int] = collections.defaultdict(int)
        self._opened_at = 0.0
        self._last_flush = 0.0
        # front state
        self._last_ns = 0
        self._last_disk_check = -1e9
        self._free = 1 << 62
        self._metadata: dict[str, dict[str, str]] = {}
        self.files: list[Path] = []
        self.written = 0
        self.dropped: dict[str, int] = collections.Counter()
        self.raw_stopped = False
        self.all_stopped = False
        self._closed = False
        # disk faults: set by the writer thread, read by the front
        self.failing = False
        self.error = ""
        self._retry_at = 0.0
        self._backoff = 0.0
        self._last_error_log = -1e9
        self._not_recorded_since_log = 0
        self._file_messages = 0       # messages given to the open file ...
        self._durable = 0             # ... of which in chunks that reached the OS
        self._durable_bytes = 0
        self._file_path: Path | None = None

    # ------------------------------------------------------------------ life
    def open(self) -> Recorder:
        """Start recording; a folder or disk that fails does not raise: the recorder starts
        failing (stats say so) and retries after its back-off."""
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            if self.config_text:
                stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
                (self.dir / f"{self.prefix}-{stamp}.config.toml").write_text(self.config_text)
            with self._lock:
                self._check_disk(force=True)
            if not self.all_stopped:
                self._start_file()
        except OSError as exc:
            self._fault(exc, f"cannot start recording in {self.dir}")
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()
        return self

    def __enter__(self) -> Recorder:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Write what is queued, finish the file (summary + footer); safe twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._thread is not None:
            self._queue.put(("stop",))
            self._thread.join(CLOSE_TIMEOUT_S)
            self._thread = None
        else:
            self._finish_file()

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=min(self.cfg.flush_s, 0.5))
            except queue.Empty:
                try:
                    self._flush_if_due()
                except OSError as exc:
                    self._fault(exc, f"cannot write {self.files[-1] if self.files else self.dir}")
                continue
            op = item[0]
            try:
                if op == "msg":
                    if self.failing and not self._retry_due():
                        self._lost()
                        continue
                    self._write_now(*item[1:])
                    self._recovered()
                elif op == "meta":
                    if self._writer is not None:
                        self._writer.add_metadata(item[1], item[2])
                elif op == "finish":
                    self._finish_file()
                elif op == "stop":
                    try:
                        self._finish_file()
                    except OSError as exc:  # the file keeps what reached the disk
                        self._fault(exc, "cannot finish the log file")
                    return
                self._flush_if_due()
            except OSError as exc:  # disk error: the file is given up, a new one after the back-off
                if op == "msg":
                    self._lost()
                self._fault(exc, f"cannot write {self.files[-1] if self.files else self.dir}")

    # ------------------------------------------------------------------ disk faults
    def _retry_due(self) -> bool:
        return self._monotonic() >= self._retry_at

    def _lost(self, n: int = 1) -> None:
        with self._lock:
            self.dropped["disk_error"] += n
            self._not_recorded_since_log += n

    def _fault(self, exc: OSError, what: str) -> None:
        """Give up the file (removed when nothing was recorded in it), back off, log rarely.
        Messages of the open chunk are lost with it and counted."""
        if self._file is not None and self._file_messages > self._durable:
            self.written -= self._file_messages - self._durable
            self._lost(self._file_messages - self._durable)
            self._file_messages = self._durable
        self._abandon_file()
        now = self._monotonic()
        self._backoff = min(max(2 * self._backoff, 1.0), self.cfg.retry_s)
        self._retry_at = now + self._backoff
        first = not self.failing
        self.error = f"{what}: {exc.strerror or exc}"
        self.failing = True
        if first or now - self._last_error_log >= self.cfg.error_interval_s:
            with self._lock:
                lost, self._not_recorded_since_log = self._not_recorded_since_log, 0
            log.error("recorder: %s; not recording (%d message(s) lost since the last report), "
                      "next try in %.1f s", self.error, lost, self._backoff)
            self._last_error_log = now

    def _recovered(self) -> None:
        if not self.failing:
            return
        with self._lock:
            lost, self._not_recorded_since_log = self._not_recorded_since_log, 0
        log.warning("recorder: recording again to %s (%d message(s) were not recorded)",
                    self.files[-1] if self.files else self.dir, lost)
        self.failing, self.error, self._backoff = False, "", 0.0

    def _write_now(self, topic: str, log_ns: int, pub_ns: int, payload: bytes | Callable) -> None:
        if callable(payload):  # a deferred record: encoded here, off the caller's thread
            try:
                payload = _encode(payload())
            except Exception:  # a bug in an encoder costs that record, not the log
                self.dropped["encode_error"] += 1
                log.exception("recorder: cannot encode a %s record", topic)
                return
        if self._writer is None:
            self._start_file()
        self._maybe_rotate()
        cid = self._channel(topic)
        self._writer.add_message(channel_id=cid, log_time=log_ns, publish_time=pub_ns,
                                 data=payload, sequence=self._seq[cid])
        self._seq[cid] += 1
        self.written += 1
        self._file_messages += 1
        self._note_durable()

    def _flush_if_due(self) -> None:
        """Close the open chunk at least every flush_s: a crash loses at most that much."""
        now = self._monotonic()
        if self._writer is not None and now - self._last_flush >= self.cfg.flush_s:
            self._writer.flush()
            self._last_flush = now
            self._note_durable()

    def _note_durable(self) -> None:
        """The file grew: a chunk with every message so far reached the OS."""
        if self._file is not None and self._file.tell() > self._durable_bytes:
            self._durable_bytes = self._file.tell()
            self._durable = self._file_messages

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

        self.dir.mkdir(parents=True, exist_ok=True)  # the folder may have gone with the disk
        path = self._new_path()
        self._file = _RawFile(path)
        self._file_path = path
        self._file_messages = self._durable = self._durable_bytes = 0
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}[self.cfg.compression]
        self._writer = Writer(self._file, chunk_size=int(self.cfg.chunk_kb * 1024), compression=comp)
        self._writer.start(profile="", library="mmatch-edge")
        if self.config_text:
            self._writer.add_metadata("config", {"toml": self.config_text})
        with self._lock:
            metas = dict(self._metadata)
        for name, meta in metas.items():
            self._writer.add_metadata(name, meta)
        self._channels.clear()
        self._schemas.clear()
        self._opened_at = self._monotonic()
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

    def _abandon_file(self) -> None:
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass
            if self._file_messages == 0:  # nothing recorded in it: no empty files left behind
                try:
                    os.unlink(self._file_path)
                except OSError:
                    pass
                if self.files and self.files[-1] == self._file_path:
                    self.files.pop()
        self._writer, self._file = None, None

    def _maybe_rotate(self) -> None:
        assert self._file is not None
        age = self._monotonic() - self._opened_at
        if self._file.tell() >= self.cfg.rotate_mb * MB or age >= self.cfg.rotate_s:
            self._finish_file()
            self._start_file()

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

    # ------------------------------------------------------------------ front
    def set_metadata(self, name: str, meta: dict[str, str]) -> None:
        """A metadata record written now and at the start of every later file."""
        with self._lock:
            self._metadata[name] = dict(meta)
            if not self._closed and self._thread is not None:
                self._queue.put(("meta", name, dict(meta)))

    def _check_disk(self, force: bool = False) -> None:
        now = self._monotonic()
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
            if all_stop and self._thread is not None:
                self._queue.put(("finish",))  # a complete, indexed file before the disk fills
        self.raw_stopped, self.all_stopped = raw_stop, all_stop

    def _next_ns(self) -> int:
        t = max(self._clock_ns(), self._last_ns + 1)
        self._last_ns = t
        return t

    def write(self, topic: str, data: bytes | dict | Callable[[], bytes | dict],
              stamp: float | None = None) -> bool:
        """Queue one message; False (and counted) when the disk floor, a full queue or a close
        refuses it. Log times are strictly increasing in call order across threads.

        `data`: bytes (raw, protobuf), a dict (JSON), or a function of no argument returning
        either, called on the writer thread (views that cost encoding time, e.g. Foxglove
        scenes, stay off the loop); its log time is still taken here, in call order."""
        payload = data if callable(data) else _encode(data)
        logschema.schema_for(topic)  # an unknown topic is a bug: raise in the caller
        with self._lock:
            if self._closed or self._thread is None:
                self.dropped["closed"] += 1
                return False
            self._check_disk()
            if self.all_stopped:
                self.dropped["disk_floor"] += 1
                return False
            if self.raw_stopped and logschema.is_raw(topic):
                self.dropped["raw_disk_floor"] += 1
                return False
            if self.failing and self._monotonic() < self._retry_at:  # backing off: not even queued
                self.dropped["disk_error"] += 1
                self._not_recorded_since_log += 1
                return False
            log_ns = self._next_ns()
            pub_ns = log_ns if stamp is None else max(int(round(stamp * 1e9)), 0)
            try:
                self._queue.put_nowait(("msg", topic, log_ns, pub_ns, payload))
            except queue.Full:
                self.dropped["queue_full"] += 1
                return False
        return True

    def stats(self) -> dict[str, Any]:
        with self._lock:
            state = ("closed" if self._closed else "failing" if self.failing
                     else "below floor" if self.all_stopped else "recording")
            return {"state": state, "error": self.error, "written": self.written,
                    "queued": self._queue.qsize(), "files": len(self.files),
                    "dropped": dict(self.dropped), "raw_stopped": self.raw_stopped,
                    "all_stopped": self.all_stopped, "free_mb": round(self._free / MB, 1)}
