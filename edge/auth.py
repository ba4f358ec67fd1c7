"""Who may talk to whom: Ed25519 signing keys, the fleet trust file, and checking what arrives.

Every shared frame (wire version 2, `mmatch.codec`) and every fused or health message
(`seal_message`) is signed by its sender's private key over all bytes before the
signature. A receiver keeps the fleet's public keys in a trust file and accepts a frame only
when, in this order (the cheap checks first, so a flood cannot make it verify):

1. its size, header and counts are sound and within the caps      -> else "size" / "malformed" / "caps"
2. the sender inside equals the vehicle of its key expression      -> else "sender_mismatch"
3. the sender is in the trust file, with the key id of the frame   -> else "unknown_sender" / "unknown_key"
4. its stamp lies in [now - behind_s, now + ahead_s]               -> else "stale" / "future"
   (the lower end moves back while the receiver's own frames lag: `pairing_horizon`)
5. its sequence number is above the last accepted from that sender -> else "replay"
6. the Ed25519 signature verifies                                  -> else "bad_signature"
7. the records decode within the caps (positions within range)     -> else "malformed" / "caps"

Refusals raise `Rejected` (a DecodeError) carrying the reason, and are counted by reason.

Trust file (TOML), one entry per vehicle, several keys while a key is being rotated:

    [vehicles]
    cav1 = ["<base64 of the raw 32-byte Ed25519 public key>"]
    ego1 = ["...", "..."]

It is re-read when it changes on disk (checked at most once a second) or when
`request_reload` is called (the service does on SIGHUP); a broken new file is refused and
the old trust stays. Private keys are PKCS#8 PEM files, readable by their owner only.

Sequence numbers are microseconds of the sender's clock when they would not exceed the
previous one (`Sequence`), so they keep increasing across a restart of the sender.
"""

from __future__ import annotations

import base64
import collections
import contextlib
import fcntl
import hashlib
import json
import logging
import os
import struct
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mmatch import codec
from mmatch.errors import ConfigError, DecodeError
from mmatch.shared import SharedFrame

log = logging.getLogger(__name__)

PUBLIC_KEY_BYTES = 32
MESSAGE_MAGIC = b"MMSM"
MESSAGE_VERSION = 2
#: message kinds: a signed message names what it is, so a health message cannot pass as fused
MESSAGE_KINDS = {"fused": 1, "health": 2}
_MSG_HEADER = struct.Struct("<4sBBI8s")   # magic, version, kind, total length, key id
_MSG_META = struct.Struct("<Qd")          # seq, stamp
MAX_MESSAGE_BYTES = 1 << 20

REASONS = ("size", "malformed", "caps", "sender_mismatch", "unknown_sender", "unknown_key", "stale",
           "future", "replay", "bad_signature")


class Rejected(DecodeError):
    """An input refused by the receiver's checks; `reason` is one of REASONS."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def key_id(public_raw: bytes) -> bytes:
    """The 8-byte id of a raw Ed25519 public key: the first bytes of its SHA-256."""
    return hashlib.sha256(bytes(public_raw)).digest()[:codec.KEY_ID_BYTES]


def _raw_public(public_key: Any) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return public_key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


# --------------------------------------------------------------------------- keys on disk

def generate_key(path: str | Path) -> bytes:
    """Write a new Ed25519 private key (PKCS#8 PEM, mode 0600; refuses to overwrite);
    returns its raw public key."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    return _raw_public(key.public_key())


def load_private_key(path: str | Path, key: str = "auth.key_file") -> Any:
    """An Ed25519 private key from a PEM file; ConfigError naming `key` and the path."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"{key}: cannot read {path}: {exc.strerror or exc}") from exc
    try:
        private = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{key}: {path} is not an unencrypted PEM private key ({exc})") from exc
    if not isinstance(private, Ed25519PrivateKey):
        raise ConfigError(f"{key}: {path} holds a {type(private).__name__}, not an Ed25519 key")
    return private


def write_trust(path: str | Path, vehicles: dict[str, list[bytes]]) -> None:
    """Write a trust file atomically (a reader never sees half of it)."""
    lines = ["# mmatch fleet trust file: the Ed25519 public keys each vehicle signs with",
             "# (raw 32 bytes, base64). Several keys for one vehicle while a key is rotated.",
             "[vehicles]"]
    for name in sorted(vehicles):
        keys = ", ".join(f'"{base64.b64encode(k).decode()}"' for k in vehicles[name])
        lines.append(f'"{name}" = [{keys}]')
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)


def read_trust(path: str | Path) -> dict[str, dict[bytes, bytes]]:
    """{vehicle: {key id: raw public key}} of a trust file; ConfigError naming the entry."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: no such trust file") from exc
    except IsADirectoryError as exc:
        raise ConfigError(f"{path}: is a folder, not a trust file") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text ({exc})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    unknown = sorted(set(data) - {"vehicles"})
    if unknown:
        raise ConfigError(f"{path}: {unknown[0]}: unknown key (known: vehicles)")
    vehicles = data.get("vehicles", {})
    if not isinstance(vehicles, dict):
        raise ConfigError(f"{path}: vehicles: expected a table")
    out: dict[str, dict[bytes, bytes]] = {}
    for name, keys in vehicles.items():
        if not isinstance(keys, list) or not keys:
            raise ConfigError(f"{path}: vehicles.{name}: expected a list of base64 public keys")
        ids: dict[bytes, bytes] = {}
        for i, k in enumerate(keys):
            try:
                raw = base64.b64decode(k, validate=True) if isinstance(k, str) else b""
            except ValueError:
                raw = b""
            if len(raw) != PUBLIC_KEY_BYTES:
                raise ConfigError(f"{path}: vehicles.{name}[{i}]: not a base64 raw 32-byte Ed25519 public key")
            ids[key_id(raw)] = raw
        out[str(name)] = ids
    return out


# --------------------------------------------------------------------------- signing

class Signer:
    """Signs as one vehicle: `key_id`, `sign(message)`; one `Sequence` per stream."""

    def __init__(self, vehicle: str, private_key: Any) -> None:
        self.vehicle = vehicle
        self._key = private_key
        self.public_raw = _raw_public(private_key.public_key())
        self.key_id = key_id(self.public_raw)

    @classmethod
    def from_file(cls, vehicle: str, path: str | Path) -> Signer:
        return cls(vehicle, load_private_key(path))

    def sign(self, message: bytes) -> bytes:
        return self._key.sign(bytes(message))


class Sequence:
    """Strictly increasing uint64 sequence numbers that keep increasing across restarts:
    max(previous + 1, microseconds of the wall clock)."""

    def __init__(self, clock_us: Callable[[], int] = lambda: time.time_ns() // 1000) -> None:
        self._clock_us = clock_us
        self._last = 0
        self._lock = threading.Lock()

    def next(self) -> int:
        with self._lock:
            self._last = max(self._last + 1, int(self._clock_us()))
            return self._last


def seal_message(signer: Signer, kind: str, body: bytes, seq: int, stamp: float) -> bytes:
    """A signed message: MMSM | version | kind | length | key id | sender | seq | stamp | body | sig.

    body: the message (JSON bytes); stamp: s, the sender's clock.
    """
    sender = signer.vehicle.encode("utf-8")
    if len(sender) > codec.MAX_SENDER_BYTES:
        raise ValueError(f"sender id longer than {codec.MAX_SENDER_BYTES} bytes")
    total = _MSG_HEADER.size + 1 + len(sender) + _MSG_META.size + len(body) + codec.SIGNATURE_BYTES
    signed = b"".join([_MSG_HEADER.pack(MESSAGE_MAGIC, MESSAGE_VERSION, MESSAGE_KINDS[kind], total,
                                        signer.key_id),
                       bytes([len(sender)]), sender, _MSG_META.pack(int(seq), float(stamp)), body])
    return signed + signer.sign(signed)


@dataclass(frozen=True)
class MessageHeader:
    key_id: bytes
    kind: str
    sender: str
    seq: int
    stamp: float
    body: bytes


def message_header(data: bytes) -> MessageHeader:
    """The fields of a signed message (structure checked, signature not)."""
    n = len(data)
    if n < _MSG_HEADER.size + 1 + _MSG_META.size + codec.SIGNATURE_BYTES:
        raise Rejected("size", f"{n} bytes is too short for a signed message")
    if n > MAX_MESSAGE_BYTES:
        raise Rejected("size", f"{n} bytes > {MAX_MESSAGE_BYTES}")
    magic, version, kind, total, kid = _MSG_HEADER.unpack_from(data, 0)
    names = {v: k for k, v in MESSAGE_KINDS.items()}
    if magic != MESSAGE_MAGIC or version != MESSAGE_VERSION or kind not in names or total != n:
        raise Rejected("malformed", "not a signed mmatch message of this version")
    off = _MSG_HEADER.size
    slen = data[off]
    off += 1
    if slen > codec.MAX_SENDER_BYTES or off + slen + _MSG_META.size > n - codec.SIGNATURE_BYTES:
        raise Rejected("malformed", "bad sender field")
    try:
        sender = bytes(data[off:off + slen]).decode("utf-8")
    except UnicodeDecodeError:
        raise Rejected("malformed", "sender is not UTF-8") from None
    off += slen
    seq, stamp = _MSG_META.unpack_from(data, off)
    off += _MSG_META.size
    if stamp != stamp or stamp in (float("inf"), float("-inf")):
        raise Rejected("malformed", "stamp is not finite")
    return MessageHeader(bytes(kid), names[kind], sender, int(seq), float(stamp),
                         bytes(data[off:n - codec.SIGNATURE_BYTES]))


# --------------------------------------------------------------------------- trust

class TrustStore:
    """The fleet's public keys from a trust file, re-read when the file changes.

    `lookup(vehicle, key_id)` returns the public key object or raises Rejected
    ("unknown_sender" / "unknown_key"). Thread-safe.
    """

    def __init__(self, path: str | Path, poll_s: float = 1.0,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.path = Path(path)
        self.poll_s = poll_s
        self._monotonic = monotonic
        self._lock = threading.Lock()
        self._keys: dict[str, dict[bytes, Any]] = {}
        self._stat: tuple | None = None
        self._next_check = 0.0
        self._reload_asked = False
        self.loads = 0
        self.reload_errors = 0
        self._load()  # a broken file at start is a config error

    def _file_stat(self) -> tuple | None:
        try:
            st = os.stat(self.path)
        except OSError:
            return None
        return (st.st_ino, st.st_mtime_ns, st.st_size)

    def _load(self) -> None:
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

        stat = self._file_stat()
        raw = read_trust(self.path)
        keys = {v: {kid: Ed25519PublicKey.from_public_bytes(pk) for kid, pk in ids.items()}
                for v, ids in raw.items()}
        with self._lock:
            self._keys, self._stat = keys, stat
            self.loads += 1
        log.info("trust file %s: %d vehicle(s), %d key(s)", self.path, len(keys),
                 sum(len(k) for k in keys.values()))

    def request_reload(self) -> None:
        """Re-read the file at the next lookup (e.g. on SIGHUP); safe from a signal handler."""
        self._reload_asked = True

    def maybe_reload(self) -> bool:
        """Re-read the file when asked to or when it changed; True when new keys were loaded."""
        now = self._monotonic()
        if not self._reload_asked and now < self._next_check:
            return False
        self._next_check = now + self.poll_s
        asked, self._reload_asked = self._reload_asked, False
        stat = self._file_stat()
        if not asked and stat == self._stat:
            return False
        try:
            self._load()
        except ConfigError as exc:
            with self._lock:
                self._stat = stat  # one error per change, not one per poll
                self.reload_errors += 1
            log.error("trust file not reloaded, keeping the previous keys: %s", exc)
            return False
        return True

    def vehicles(self) -> list[str]:
        with self._lock:
            return sorted(self._keys)

    def lookup(self, vehicle: str, kid: bytes) -> Any:
        self.maybe_reload()
        with self._lock:
            ids = self._keys.get(vehicle)
        if ids is None:
            raise Rejected("unknown_sender", f"{vehicle!r} is not in the trust file")
        key = ids.get(kid)
        if key is None:
            raise Rejected("unknown_key", f"key {kid.hex()} is not one of {vehicle!r}'s")
        return key

    def stats(self) -> dict[str, Any]:
        with self._lock:
            return {"file": str(self.path), "vehicles": len(self._keys), "loads": self.loads,
                    "reload_errors": self.reload_errors}


class Verifier:
    """Checks received frames and messages against a TrustStore (order: module docstring).

    ahead_s / behind_s: the acceptance window of a stamp around `clock()` (s).
    limits: the decode caps. Thread-safe; `counts` holds refusals by reason and "accepted".
    """

    def __init__(self, trust: TrustStore, *, ahead_s: float, behind_s: float,
                 limits: codec.Limits = codec.LIMITS, clock: Callable[[], float] = time.time,
                 message_behind_s: float = 10.0) -> None:
        self.trust = trust
        self.ahead_s = ahead_s
        self.behind_s = behind_s
        self.message_behind_s = message_behind_s
        self.limits = limits
        self.clock = clock
        #: the oldest stamp a frame could still pair with (s); an Ego whose own frames lag
        #: behind the clock (an overloaded machine) sets it, so frames it can use are not stale
        self.pairing_horizon = float("inf")
        self._lock = threading.Lock()
        self._last_seq: dict[tuple[str, str], int] = {}
        self.counts: collections.Counter = collections.Counter()

    def _refuse(self, reason: str, detail: str) -> Rejected:
        with self._lock:
            self.counts[reason] += 1
        return Rejected(reason, detail)

    def _check(self, stream: tuple[str, str], kid: bytes, seq: int, stamp: float,
               behind_s: float, horizon: float = float("inf")) -> Any:
        try:
            key = self.trust.lookup(stream[0], kid)
        except Rejected as exc:
            raise self._refuse(exc.reason, str(exc)) from None
        now = self.clock()
        if stamp > now + self.ahead_s:
            raise self._refuse("future", f"stamp {stamp - now:+.3f} s from our clock")
        if stamp < min(now - behind_s, horizon):
            raise self._refuse("stale", f"stamp {stamp - now:+.3f} s from our clock")
        with self._lock:
            last = self._last_seq.get(stream, -1)
        if seq <= last:
            raise self._refuse("replay", f"seq {seq} not above {last}")
        return key

    def _commit(self, stream: tuple[str, str], seq: int) -> bool:
        with self._lock:
            if seq <= self._last_seq.get(stream, -1):  # a concurrent copy got in first
                self.counts["replay"] += 1
                return False
            self._last_seq[stream] = seq
            self.counts["accepted"] += 1
            return True

    def open_frame(self, vehicle: str, data: bytes,
                   decode: Callable[[bytes], SharedFrame] = codec.decode) -> SharedFrame:
        """The decoded frame when every check passes; raises Rejected (counted) otherwise."""
        from cryptography.exceptions import InvalidSignature

        if not isinstance(data, (bytes, bytearray)) or len(data) > self.limits.max_frame_bytes:
            raise self._refuse("size", f"{len(data)} bytes > {self.limits.max_frame_bytes}")
        try:
            h = codec.header(data, self.limits)
        except codec.OverCaps as exc:
            raise self._refuse("caps", str(exc)) from None
        except DecodeError as exc:
            raise self._refuse("malformed", str(exc)) from None
        if h.sender != vehicle:
            raise self._refuse("sender_mismatch", f"frame from {h.sender!r} published under {vehicle!r}")
        stream = (vehicle, "shared")
        key = self._check(stream, h.key_id, h.seq, h.stamp, self.behind_s, self.pairing_horizon)
        signed, signature = codec.split_signature(bytes(data))
        try:
            key.verify(signature, signed)
        except InvalidSignature:
            raise self._refuse("bad_signature", f"frame {h.seq} from {vehicle!r}") from None
        try:
            frame = decode(bytes(data))
            if frame.sender != vehicle:
                raise DecodeError("sender changed")
            codec.check_range(frame, self.limits)
        except codec.OverCaps as exc:
            raise self._refuse("caps", str(exc)) from None
        except DecodeError as exc:  # signed by a fleet key, yet broken: a sender bug
            raise self._refuse("malformed", str(exc)) from None
        if not self._commit(stream, h.seq):
            raise Rejected("replay", f"seq {h.seq} from {vehicle!r} came twice")
        return frame

    def open_message(self, vehicle: str, kind: str, data: bytes) -> dict:
        """The JSON body of a signed fused/health message from `vehicle`; raises Rejected."""
        from cryptography.exceptions import InvalidSignature

        try:
            h = message_header(bytes(data))
        except Rejected as exc:
            raise self._refuse(exc.reason, str(exc)) from None
        if h.sender != vehicle or h.kind != kind:
            raise self._refuse("sender_mismatch", f"{h.kind} from {h.sender!r} published as {kind} of {vehicle!r}")
        stream = (vehicle, kind)
        key = self._check(stream, h.key_id, h.seq, h.stamp, self.message_behind_s)
        try:
            key.verify(bytes(data[-codec.SIGNATURE_BYTES:]), bytes(data[:-codec.SIGNATURE_BYTES]))
        except InvalidSignature:
            raise self._refuse("bad_signature", f"{kind} {h.seq} from {vehicle!r}") from None
        try:
            body = json.loads(h.body)
        except ValueError as exc:
            raise self._refuse("malformed", f"body is not JSON: {exc}") from None
        if not self._commit(stream, h.seq):
            raise Rejected("replay", f"seq {h.seq} from {vehicle!r} came twice")
        return body

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)


# --------------------------------------------------------------------------- dev keys

def default_dev_dir() -> Path:
    """Where simulated vehicles on this machine keep their generated dev keys."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mmatch" / "dev-keys"


def dev_identity(folder: str | Path, vehicle: str) -> tuple[Path, Path]:
    """(private key file, trust file) of a simulated vehicle's dev key in `folder`.

    The key is generated on first use and its public key added to the folder's trust file
    (under a lock: several processes may start at once). Dev keys exist only on the machine
    that made them; every vehicle using the folder trusts every other one.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.chmod(folder, 0o700)
    except OSError as exc:
        raise ConfigError(f"auth.dev_dir: cannot create {folder}: {exc.strerror or exc}") from exc
    key_path, trust_path = folder / f"{vehicle}.key", folder / "trust.toml"
    with open(folder / ".lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not key_path.exists():
            generate_key(key_path)
        public = Signer(vehicle, load_private_key(key_path, "auth.dev_dir")).public_raw
        current: dict[str, list[bytes]] = {}
        if trust_path.exists():
            with contextlib.suppress(ConfigError):
                current = {v: list(ids.values()) for v, ids in read_trust(trust_path).items()}
        if public not in current.get(vehicle, []):
            current[vehicle] = [public]  # a regenerated dev key replaces the old one
            write_trust(trust_path, current)
    return key_path, trust_path


# --------------------------------------------------------------------------- from the config

@dataclass
class Identity:
    """What a running vehicle signs with and trusts. mode: "files" or "dev" (generated keys,
    simulation only: health says so)."""

    mode: str
    signer: Signer
    trust: TrustStore | None
    key_file: Path
    trust_file: Path | None

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"keys": self.mode, "key_id": self.signer.key_id.hex()}
        if self.mode == "dev":
            out["warning"] = "DEV KEYS generated on this machine: simulation only, not for the field"
        if self.trust is not None:
            out["trust"] = self.trust.stats()
        return out


def identity(cfg: Any, *, need_trust: bool | None = None) -> Identity:
    """The signer (and, for an Ego, the trust store) the config names; ConfigError naming
    auth.key_file / auth.trust_file when they are missing or unreadable."""
    from mmatch.edge.config import auth_mode

    a = cfg.auth
    need_trust = cfg.is_ego if need_trust is None else need_trust
    mode = auth_mode(cfg)
    if mode == "dev":
        key_path, dev_trust = dev_identity(Path(a.dev_dir) if a.dev_dir else default_dev_dir(),
                                           cfg.vehicle.id)
        trust_path = Path(a.trust_file) if a.trust_file else dev_trust
        log.warning("auth: DEV KEYS for %s from %s (simulation only; set auth.key_file and "
                    "auth.trust_file in the field)", cfg.vehicle.id, key_path)
    else:
        if not a.key_file:
            raise ConfigError("auth.key_file: required (make the fleet's keys with `mmatch keys`; "
                              "auth.keys = \"dev\" only for simulated vehicles)")
        if need_trust and not a.trust_file:
            raise ConfigError("auth.trust_file: required for an Ego (the fleet's public keys, "
                              "from `mmatch keys`)")
        key_path, trust_path = Path(a.key_file), Path(a.trust_file) if a.trust_file else None
    signer = Signer.from_file(cfg.vehicle.id, key_path)
    trust = None
    if need_trust and trust_path is not None:
        try:
            trust = TrustStore(trust_path)
        except ConfigError as exc:
            raise ConfigError(f"auth.trust_file: {exc}") from None
    return Identity(mode, signer, trust, key_path, trust_path)


def limits_of(cfg: Any) -> codec.Limits:
    """The decode caps of a vehicle config (ego.max_*)."""
    e = cfg.ego
    return codec.Limits(max_vehicles=e.max_vehicles, max_points=e.max_points,
                        max_background=e.max_background, max_range_m=e.max_range_m)


def verifier_for(cfg: Any, trust: TrustStore, clock: Callable[[], float] = time.time) -> Verifier:
    """A Verifier with the config's acceptance window and decode caps."""
    return Verifier(trust, ahead_s=cfg.auth.ahead_s, behind_s=cfg.auth.behind_s,
                    limits=limits_of(cfg), clock=clock)
