"""Zenoh transport between vehicles: one session per process, explicit endpoints.

Peer mode listens and/or connects on the configured endpoints; client mode connects to
a `zenohd` router (cfg/zenoh/router.json5). Multicast scouting, gossip and shared memory
are off unless the config turns them on (LIBRARIES.md section 2: the defaults listen on
every interface and scout by multicast). Key expressions come from `mmatch.edge.keys`.

Incoming samples are handed to a callback on a Zenoh thread; a payload on a foreign key,
one larger than `max_payload` (checked before it is copied) or one the receiver refuses is
dropped and counted by reason, never raised.
"""

from __future__ import annotations

import collections
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, TypeVar

from mmatch.edge import keys
from mmatch.edge.config import ZenohSection
from mmatch.errors import ConfigError, DecodeError, DeviceError

log = logging.getLogger(__name__)

T = TypeVar("T")


class KeepNewest(Generic[T]):
    """A bounded, thread-safe queue that keeps the newest items.

    `put` never blocks: when full, the oldest item is dropped and counted in `dropped`.
    `get` blocks up to `timeout` seconds and returns None when nothing came.
    """

    def __init__(self, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError("maxlen must be >= 1")
        self._items: collections.deque[T] = collections.deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0
        self.put_count = 0
        self._closed = False

    def put(self, item: T) -> None:
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.put_count += 1
            self._cond.notify()

    def get(self, timeout: float | None = None) -> T | None:
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            return self._items.popleft() if self._items else None

    def get_newest(self, timeout: float | None = None) -> T | None:
        """The newest item; older waiting items are discarded (and counted as dropped)."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if not self._items:
                return None
            item = self._items.pop()
            self.dropped += len(self._items)
            self._items.clear()
            return item

    def close(self) -> None:
        """Wake every waiter; later gets return what is left, then None."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


def zenoh_config_json(cfg: ZenohSection) -> dict[str, Any]:
    """The zenoh settings we impose, as {json5 key path: value}."""
    if cfg.mode == "client" and not cfg.connect:
        raise ConfigError("zenoh.connect: client mode needs a router endpoint")
    out: dict[str, Any] = {
        "mode": cfg.mode,
        "connect/endpoints": list(cfg.connect),
        "scouting/multicast/enabled": bool(cfg.multicast_scouting),
        "scouting/gossip/enabled": bool(cfg.gossip),
        "transport/shared_memory/enabled": bool(cfg.shared_memory),
    }
    if cfg.mode == "peer":
        # Always explicit: the default listens on tcp/[::]:0, i.e. every interface.
        out["listen/endpoints"] = list(cfg.listen)
    elif cfg.listen:
        out["listen/endpoints"] = list(cfg.listen)
    if cfg.tls_root_ca:  # mutual TLS: the same certificate when listening and when connecting
        tls = "transport/link/tls/"
        out[tls + "root_ca_certificate"] = cfg.tls_root_ca
        out[tls + "enable_mtls"] = True
        out[tls + "verify_name_on_connect"] = bool(cfg.tls_verify_name)
        for side in ("listen", "connect"):
            out[f"{tls}{side}_certificate"] = cfg.tls_certificate
            out[f"{tls}{side}_private_key"] = cfg.tls_private_key
    return out


def _check_file(key: str, path: str) -> None:
    """ConfigError naming `key` when `path` is not a readable file."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{key}: {path} is a folder, not a file")
    if not p.is_file():
        raise ConfigError(f"{key}: {path}: no such file")
    if not os.access(p, os.R_OK):
        raise ConfigError(f"{key}: {path}: not readable")


def make_zenoh_config(cfg: ZenohSection) -> Any:
    """A `zenoh.Config` from our section (on top of `config_file` when given)."""
    import zenoh

    for key in ("config_file", "tls_root_ca", "tls_certificate", "tls_private_key"):
        if getattr(cfg, key):
            _check_file(f"zenoh.{key}", getattr(cfg, key))
    try:
        zconf = zenoh.Config.from_file(cfg.config_file) if cfg.config_file else zenoh.Config()
        for key, value in zenoh_config_json(cfg).items():
            zconf.insert_json5(key, json.dumps(value))
    except ConfigError:
        raise
    except Exception as exc:  # zenoh raises ZError for bad files and endpoints
        where = f"zenoh.config_file: {cfg.config_file}: " if cfg.config_file else "zenoh: "
        raise ConfigError(f"{where}{exc}") from exc
    return zconf


class DropCounter:
    """Thread-safe counters of dropped inputs by reason."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts: dict[str, int] = collections.Counter()

    def add(self, reason: str, n: int = 1) -> None:
        with self._lock:
            self.counts[reason] += n

    def total(self) -> int:
        with self._lock:
            return sum(self.counts.values())

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)


#: the encoding each kind of sample carries (docs/formats.md); anything else is plain bytes
ENCODINGS: dict[str, str] = {
    "shared": "application/vnd.mmatch.shared-frame",
    "fused": "application/vnd.mmatch.signed-message",    # JSON inside a signed envelope (edge/auth.py)
    "health": "application/vnd.mmatch.signed-message",
}


def _publisher_qos(key: str) -> dict[str, Any]:
    """Sensor-like streams: never block the loop (drop under congestion), no batching delay
    (express); shared frames first, fused results next, health in the background. Each
    sample says what it holds (`ENCODINGS`)."""
    import zenoh

    kind = (keys.parse(key) or ("", ""))[1]
    priority = {"shared": zenoh.Priority.REAL_TIME, "fused": zenoh.Priority.INTERACTIVE_HIGH,
                "health": zenoh.Priority.BACKGROUND}.get(kind, zenoh.Priority.DATA)
    encoding = zenoh.Encoding(ENCODINGS[kind]) if kind in ENCODINGS else zenoh.Encoding.ZENOH_BYTES
    return {"congestion_control": zenoh.CongestionControl.DROP, "express": kind != "health",
            "priority": priority, "encoding": encoding}


class Transport:
    """One Zenoh session with our publishers and subscribers. A context manager."""

    def __init__(self, cfg: ZenohSection) -> None:
        self.cfg = cfg
        self._session: Any = None
        self._publishers: dict[str, Any] = {}
        self._subscribers: list[Any] = []
        self._lock = threading.Lock()
        self.drops = DropCounter()
        self.published = 0
        self.received = 0

    def open(self) -> Transport:
        import zenoh

        conf = make_zenoh_config(self.cfg)
        try:
            self._session = zenoh.open(conf)
        except Exception as exc:
            raise DeviceError(f"zenoh: cannot open session ({self.cfg.mode}, listen={self.cfg.listen}, "
                              f"connect={self.cfg.connect}): {exc}") from exc
        log.info("zenoh session open: mode=%s listen=%s connect=%s", self.cfg.mode,
                 self.cfg.listen, self.cfg.connect)
        return self

    def __enter__(self) -> Transport:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything and close the session; safe to call twice."""
        with self._lock:
            session, self._session = self._session, None
            subs, self._subscribers = self._subscribers, []
            pubs, self._publishers = self._publishers, {}
        for obj in [*subs, *pubs.values()]:
            try:
                obj.undeclare()
            except Exception:  # already gone with the session
                pass
        if session is not None:
            try:
                session.close()
            except Exception as exc:  # closing twice from zenoh's side
                log.debug("zenoh close: %s", exc)

    @property
    def session(self) -> Any:
        if self._session is None:
            raise DeviceError("zenoh session is not open")
        return self._session

    def put(self, key: str, payload: bytes) -> None:
        """Publish `payload` on `key` (a publisher is declared once per key)."""
        with self._lock:
            pub = self._publishers.get(key)
            if pub is None:
                pub = self.session.declare_publisher(key, **_publisher_qos(key))
                self._publishers[key] = pub
        pub.put(payload)
        self.published += 1

    def has_subscribers(self, key: str) -> bool:
        """True when a matching subscriber is known for `key`'s publisher."""
        with self._lock:
            pub = self._publishers.get(key)
        if pub is None:
            return False
        try:
            return bool(pub.matching_status.matching)
        except Exception:
            return False

    def subscribe(self, keyexpr: str, kind: str,
                  on_payload: Callable[[str, bytes], None],
                  vehicles: list[str] | None = None, max_payload: int | None = None) -> None:
        """Call `on_payload(vehicle, payload)` for every sample on `keyexpr`.

        Samples whose key is not `mmatch/v1/<vehicle>/<kind>` (or whose vehicle is not in
        `vehicles`, when given) are dropped and counted as "foreign".
        """
        wanted = set(vehicles) if vehicles else None

        def handler(sample: Any) -> None:
            self.received += 1
            parsed = keys.parse(str(sample.key_expr))
            if parsed is None or parsed[1] != kind or (wanted is not None and parsed[0] not in wanted):
                self.drops.add("foreign")
                return
            try:
                if max_payload is not None and len(sample.payload) > max_payload:
                    self.drops.add("size")
                    return
                payload = sample.payload.to_bytes()
            except Exception:
                self.drops.add("malformed")
                return
            try:
                on_payload(parsed[0], payload)
            except DecodeError as exc:
                self.drops.add(getattr(exc, "reason", "malformed"))
                log.debug("dropped payload from %s: %s", parsed[0], exc)
            except Exception:  # a bug in the handler must not kill zenoh's thread silently
                self.drops.add("handler-error")
                log.exception("subscriber handler failed on %s", sample.key_expr)

        sub = self.session.declare_subscriber(keyexpr, handler)
        with self._lock:
            self._subscribers.append(sub)

    def wait_for_peers(self, timeout: float) -> bool:
        """Wait until at least one peer/router is connected (True) or `timeout` passes."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            info = self.session.info
            if list(info.peers_zid()) or list(info.routers_zid()):
                return True
            time.sleep(0.02)
        return False
