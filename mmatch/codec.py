"""Wire codec of the shared frame (DESIGN.md "Wire format of a shared frame"), format version 3.

Binary, little-endian, length-prefixed, signed by the sender (Ed25519), quantised:

    header   magic b"MMSF" | version u8 (=3) | flags u8 (=0) | total length u32 (whole frame, bytes)
             | key id 8 bytes (first 8 bytes of SHA-256 of the sender's raw Ed25519 public key)
    meta     sender length u8 | sender UTF-8 (<= 64 bytes) | seq u64 | stamp f64 (s)
             | radar_height f32 (m) | ego vx, vy i16 (cm/s; -32768 = unknown/NaN)
             | vehicles V u16 | vehicle points K u16 | background points B u16
             | moving points M u16 (version 3 only)
    vehicles V records: u1, v1, u2, v2 i16 (half pixels of the canonical image, shared.py)
             | score u8 (round(s*255))
             | depth u16 (cm) | box index u16 | points of this vehicle u16
             | centre x, y i16 (cm) | descriptor 32 x u8 (round(v*255))
    points   K records, grouped by vehicle in vehicle order: x, y, z i16 (cm)
             | doppler i16 (cm/s) | snr u8 (half dB)
    backgr.  B records: x, y, z i16 (cm)
    moving   M records: x, y i16 (cm) (version 3 only: the moving returns in no shared vehicle)
    sig      64 bytes: Ed25519 signature of every byte before it by the key named in the header

An unsigned frame (offline evaluation, `encode` without a signer) carries an all-zero key id
and signature; no receiver accepts it. Checking the signature, the sender's key, the sequence
number and the stamp is the receiver's job (`mmatch.edge.auth`): `header` reads what those
checks need without touching the records, so a receiver can refuse cheaply before it verifies.
Version 1 (CRC-32, no signature) is not decoded any more: an unauthenticated frame is refused.
Version 2 is version 3 without the moving count and records: it is still decoded (an empty
moving sketch), so a fleet can upgrade one vehicle at a time; `encode` writes version 3.

Quantisation losses (round to nearest): positions and centres +-0.5 cm (range +-327.67 m);
Doppler and ego velocity +-0.5 cm/s (+-327.67 m/s); box corners +-0.25 px (+-16383.5 px);
depth +-0.5 cm (0-655.35 m); score +-1/510; snr +-0.25 dB, clipped to 0-127.5 dB (TI SNR is
non-negative); descriptor bins +-1/510 each, clipped to 0-1, so a decoded group sums to 1
only within 16/510 (hue) or 8/510 (saturation, value); radar height is float32 (+-6e-8
relative); stamp is exact. A vehicle record costs 51 bytes, a point 9, a background point 6,
a moving point 4; header, meta and signature 115 bytes plus the sender (113 in version 2).

Caps (`Limits`): a frame is about one radar's view, so decoding refuses more than
`max_vehicles` vehicles, `max_points` vehicle points, `max_background` background points or
`max_moving` moving points
(checked on the counts, before any record is read) and any position, centre or depth beyond
`max_range_m`. `encode` raises EncodeError for values the format cannot carry (out of range,
NaN where a number is required, sender too long, more than 65535 items). `decode` trusts
nothing: a wrong magic, version, flags, length, count, sender text, a non-finite stamp or a
cap exceeded raises DecodeError, and no other exception escapes it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from mmatch.errors import DecodeError, MMatchError
from mmatch.shared import SharedFrame
from mmatch.types import DESCRIPTOR_DIM

MAGIC = b"MMSF"
VERSION = 3
READ_VERSIONS = (2, 3)
MAX_SENDER_BYTES = 64
VELOCITY_UNKNOWN = -32768
KEY_ID_BYTES = 8
SIGNATURE_BYTES = 64
NO_KEY = bytes(KEY_ID_BYTES)

_HEADER = struct.Struct("<4sBBI8s")
_META = struct.Struct("<QdfhhHHH")          # version 2
_META3 = struct.Struct("<QdfhhHHHH")        # version 3: one count more (moving points)

VEHICLE_DTYPE = np.dtype([("box", "<i2", (4,)), ("score", "u1"), ("depth", "<u2"),
                          ("box_index", "<u2"), ("n_points", "<u2"), ("centre", "<i2", (2,)),
                          ("descriptor", "u1", (DESCRIPTOR_DIM,))])
POINT_DTYPE = np.dtype([("xyz", "<i2", (3,)), ("doppler", "<i2"), ("snr", "u1")])
BACKGROUND_DTYPE = np.dtype([("xyz", "<i2", (3,))])
MOVING_DTYPE = np.dtype([("xy", "<i2", (2,))])

MIN_FRAME_BYTES = _HEADER.size + 1 + _META.size + SIGNATURE_BYTES


@dataclass(frozen=True)
class Limits:
    """Caps a decoder applies (a frame is about one radar's view, far below the format's limits).

    max_vehicles, max_points (vehicle points), max_background, max_moving: counts per frame;
    max_range_m: largest |x|, |y|, |z| of any point or centre and largest box depth, m.
    """

    max_vehicles: int = 128
    max_points: int = 4096
    max_background: int = 4096
    max_moving: int = 1024
    max_range_m: float = 327.68

    @property
    def max_frame_bytes(self) -> int:
        """The largest frame these caps allow (sender at its longest)."""
        return (MIN_FRAME_BYTES + MAX_SENDER_BYTES + _META3.size - _META.size
                + self.max_vehicles * VEHICLE_DTYPE.itemsize + self.max_points * POINT_DTYPE.itemsize
                + self.max_background * BACKGROUND_DTYPE.itemsize + self.max_moving * MOVING_DTYPE.itemsize)


LIMITS = Limits()


@dataclass(frozen=True)
class FrameHeader:
    """What a receiver checks before verifying: read from the fixed fields only.

    counts: (V vehicles, K vehicle points, B background points); body_offset: where the
    vehicle records start; stamp in s; seq uint64; moving: M moving points (0 in version 2);
    version: 2 or 3.
    """

    key_id: bytes
    sender: str
    seq: int
    stamp: float
    radar_height: float
    velocity_q: tuple[int, int]
    counts: tuple[int, int, int]
    body_offset: int
    moving: int = 0
    version: int = VERSION


class Signer(Protocol):
    """Anything that signs: `key_id` (8 bytes) and `sign(message) -> 64-byte signature`."""

    key_id: bytes

    def sign(self, message: bytes) -> bytes: ...


class OverCaps(DecodeError):
    """A frame beyond the decoder's `Limits` (too large, too many items, beyond the range)."""


class EncodeError(MMatchError, ValueError):
    """A SharedFrame holds a value the wire format cannot carry; the message names the field."""


def _quantise(name: str, values, scale: float, lo: int, hi: int, dtype: str) -> np.ndarray:
    """round(values * scale) as `dtype`, refusing NaN and values outside [lo, hi]."""
    v = np.asarray(values, np.float64)
    if not np.all(np.isfinite(v)):
        raise EncodeError(f"{name}: contains NaN or infinity")
    q = np.rint(v * scale)
    if q.size and (q.min() < lo or q.max() > hi):
        raise EncodeError(f"{name}: values {v.min():.3f}..{v.max():.3f} outside the wire range "
                          f"{lo / scale:.3f}..{hi / scale:.3f}")
    return q.astype(dtype)


def _rows(name: str, arr, cols: int) -> np.ndarray:
    a = np.asarray(arr)
    if a.size == 0:
        return np.zeros((0, cols), np.float64)
    if a.ndim != 2 or a.shape[1] != cols:
        raise EncodeError(f"{name}: shape {a.shape} is not (N, {cols})")
    return a.astype(np.float64)


def encode(frame: SharedFrame, signer: Signer | None = None) -> bytes:
    """Serialise a SharedFrame (format version 3), signed by `signer` when given (else the key
    id and signature are zero: an unsigned frame, for offline use). Raises EncodeError on
    unrepresentable values.

    Vehicle points are written grouped by vehicle (stable order within a vehicle), so a decoded
    frame lists them in vehicle order.
    """
    sender = frame.sender.encode("utf-8")
    if len(sender) > MAX_SENDER_BYTES:
        raise EncodeError(f"sender: {len(sender)} UTF-8 bytes > {MAX_SENDER_BYTES}")
    if not 0 <= int(frame.seq) < 2**64:
        raise EncodeError(f"seq: {frame.seq} is not a uint64")
    if not np.isfinite(frame.stamp):
        raise EncodeError("stamp: not finite")
    if not np.isfinite(frame.radar_height):
        raise EncodeError("radar_height: not finite")
    boxes = _rows("vehicle_boxes", frame.vehicle_boxes, 6)
    V = len(boxes)
    points = _rows("vehicle_points", frame.vehicle_points, 5)
    index = np.asarray(frame.vehicle_index, np.int64).reshape(-1)
    background = _rows("background", frame.background, 3)
    moving = _rows("moving", frame.moving, 2)
    centres = _rows("vehicle_centers", frame.vehicle_centers, 2)
    features = _rows("vehicle_features", frame.vehicle_features, DESCRIPTOR_DIM)
    box_index = np.asarray(frame.vehicle_box_index, np.int64).reshape(-1)
    for name, n in (("vehicle_centers", len(centres)), ("vehicle_features", len(features)),
                    ("vehicle_box_index", len(box_index))):
        if n != V:
            raise EncodeError(f"{name}: {n} rows for {V} vehicles")
    if len(index) != len(points):
        raise EncodeError(f"vehicle_index: {len(index)} entries for {len(points)} points")
    if len(index) and (index.min() < 0 or index.max() >= V):
        raise EncodeError("vehicle_index: refers to a vehicle that does not exist")
    for name, n in (("vehicles", V), ("vehicle_points", len(points)), ("background", len(background)),
                    ("moving", len(moving))):
        if n > 0xFFFF:
            raise EncodeError(f"{name}: {n} > 65535 items")

    vel = np.asarray(frame.ego_velocity, np.float64).reshape(-1)
    if vel.shape != (2,):
        raise EncodeError(f"ego_velocity: shape {vel.shape} is not (2,)")
    if np.all(np.isnan(vel)):
        vq = (VELOCITY_UNKNOWN, VELOCITY_UNKNOWN)
    else:
        vq = tuple(int(x) for x in _quantise("ego_velocity", vel, 100, -32767, 32767, "<i2"))

    veh = np.zeros(V, VEHICLE_DTYPE)
    veh["box"] = _quantise("vehicle_boxes[u1:v2]", boxes[:, :4], 2, -32768, 32767, "<i2")
    veh["score"] = _quantise("vehicle_boxes[score]", boxes[:, 4], 255, 0, 255, "u1")
    veh["depth"] = _quantise("vehicle_boxes[depth]", boxes[:, 5], 100, 0, 65535, "<u2")
    veh["box_index"] = _quantise("vehicle_box_index", box_index, 1, 0, 65535, "<u2")
    veh["n_points"] = np.bincount(index, minlength=V)[:V] if V else np.zeros(0)
    veh["centre"] = _quantise("vehicle_centers", centres, 100, -32768, 32767, "<i2")
    feats = np.where(np.isnan(features), np.nan, np.clip(features, 0.0, 1.0))
    veh["descriptor"] = _quantise("vehicle_features", feats, 255, 0, 255, "u1")

    order = np.argsort(index, kind="stable")
    pts = np.zeros(len(points), POINT_DTYPE)
    pts["xyz"] = _quantise("vehicle_points[xyz]", points[order, :3], 100, -32768, 32767, "<i2")
    pts["doppler"] = _quantise("vehicle_points[doppler]", points[order, 3], 100, -32768, 32767, "<i2")
    snr = points[order, 4]
    if not np.all(np.isfinite(snr)):
        raise EncodeError("vehicle_points[snr]: contains NaN or infinity")
    pts["snr"] = _quantise("vehicle_points[snr]", np.clip(snr, 0.0, 127.5), 2, 0, 255, "u1")
    bgr = np.zeros(len(background), BACKGROUND_DTYPE)
    bgr["xyz"] = _quantise("background", background, 100, -32768, 32767, "<i2")
    mov = np.zeros(len(moving), MOVING_DTYPE)
    mov["xy"] = _quantise("moving", moving, 100, -32768, 32767, "<i2")

    body = b"".join([
        bytes([len(sender)]), sender,
        _META3.pack(int(frame.seq), float(frame.stamp), float(frame.radar_height), vq[0], vq[1],
                    V, len(pts), len(bgr), len(mov)),
        veh.tobytes(), pts.tobytes(), bgr.tobytes(), mov.tobytes()])
    total = _HEADER.size + len(body) + SIGNATURE_BYTES
    key_id = NO_KEY if signer is None else bytes(signer.key_id)
    if len(key_id) != KEY_ID_BYTES:
        raise EncodeError(f"signer: key id of {len(key_id)} bytes (expected {KEY_ID_BYTES})")
    signed = _HEADER.pack(MAGIC, VERSION, 0, total, key_id) + body
    signature = bytes(SIGNATURE_BYTES) if signer is None else bytes(signer.sign(signed))
    if len(signature) != SIGNATURE_BYTES:
        raise EncodeError(f"signer: signature of {len(signature)} bytes (expected {SIGNATURE_BYTES})")
    return signed + signature


def split_signature(data: bytes) -> tuple[bytes, bytes]:
    """(signed bytes, signature) of a frame whose header has been checked."""
    return data[:-SIGNATURE_BYTES], data[-SIGNATURE_BYTES:]


def header(data, limits: Limits = LIMITS) -> FrameHeader:
    """Check the fixed fields and the counts of a frame without reading its records.

    Refuses (DecodeError) a frame too short or beyond what `limits` allow, a wrong magic,
    version, flags or length, a bad sender, a non-finite stamp, counts over the caps or
    counts that do not fill the bytes exactly.
    """
    return _guarded(_header, data, limits)


def _header(data, limits: Limits) -> FrameHeader:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DecodeError(f"expected bytes, got {type(data).__name__}")
    n = len(data)
    if n < MIN_FRAME_BYTES:
        raise DecodeError(f"truncated: {n} bytes < the minimum {MIN_FRAME_BYTES}")
    if n > limits.max_frame_bytes:
        raise OverCaps(f"too large: {n} bytes > {limits.max_frame_bytes} (the caps' largest frame)")
    magic, version, flags, total, key_id = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise DecodeError(f"bad magic {bytes(magic)!r} (expected {MAGIC!r})")
    if version not in READ_VERSIONS:
        readable = ", ".join(map(str, READ_VERSIONS))
        raise DecodeError(f"unsupported version {version} (this decoder reads {readable})")
    if flags != 0:
        raise DecodeError(f"unknown flags 0x{flags:02x}")
    if total != n:
        raise DecodeError(f"length field says {total} bytes, got {n}")
    end = n - SIGNATURE_BYTES
    off = _HEADER.size
    slen = data[off]
    off += 1
    if slen > MAX_SENDER_BYTES:
        raise DecodeError(f"sender length {slen} > {MAX_SENDER_BYTES}")
    meta = _META3 if version == 3 else _META
    if off + slen + meta.size > end:
        raise DecodeError("truncated meta block")
    try:
        sender = bytes(data[off:off + slen]).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DecodeError(f"sender is not UTF-8 ({exc})") from exc
    off += slen
    seq, stamp, height, vx, vy, V, K, B, *rest = meta.unpack_from(data, off)
    M = rest[0] if rest else 0
    off += meta.size
    if not (np.isfinite(stamp) and np.isfinite(height)):
        raise DecodeError("stamp or radar_height is not finite")
    if V > limits.max_vehicles or K > limits.max_points or B > limits.max_background or M > limits.max_moving:
        raise OverCaps(f"over the caps: {V} vehicles, {K} points, {B} background points, {M} moving points "
                       f"(at most {limits.max_vehicles}, {limits.max_points}, {limits.max_background}, "
                       f"{limits.max_moving})")
    need = V * VEHICLE_DTYPE.itemsize + K * POINT_DTYPE.itemsize + B * BACKGROUND_DTYPE.itemsize \
        + M * MOVING_DTYPE.itemsize
    if need != end - off:
        raise DecodeError(f"counts (V={V}, K={K}, B={B}, M={M}) need {need} bytes, {end - off} remain")
    if (vx == VELOCITY_UNKNOWN) != (vy == VELOCITY_UNKNOWN):
        raise DecodeError("ego velocity half unknown")
    return FrameHeader(bytes(key_id), sender, int(seq), float(stamp), float(height), (vx, vy),
                       (V, K, B), off, int(M), int(version))


def decode(data, limits: Limits = LIMITS) -> SharedFrame:
    """Parse and validate one encoded frame's structure and caps; any defect raises DecodeError
    (and nothing else). The signature is not checked here (see the module docstring)."""
    return _guarded(_decode, data, limits)


def _guarded(fn, data, limits: Limits):
    """fn(data, limits), letting only DecodeError out."""
    try:
        return fn(data, limits)
    except DecodeError:
        raise
    except (struct.error, ValueError, TypeError, IndexError, OverflowError) as exc:  # belt and braces
        raise DecodeError(f"malformed shared frame ({type(exc).__name__}: {exc})") from exc


def _decode(data, limits: Limits) -> SharedFrame:
    h = _header(data, limits)
    buf = bytes(data)
    V, K, B = h.counts
    off = h.body_offset
    veh = np.frombuffer(buf, VEHICLE_DTYPE, V, off)
    off += V * VEHICLE_DTYPE.itemsize
    pts = np.frombuffer(buf, POINT_DTYPE, K, off)
    off += K * POINT_DTYPE.itemsize
    bgr = np.frombuffer(buf, BACKGROUND_DTYPE, B, off)
    off += B * BACKGROUND_DTYPE.itemsize
    mov = np.frombuffer(buf, MOVING_DTYPE, h.moving, off)
    counts = veh["n_points"].astype(np.int64)
    if int(counts.sum()) != K:
        raise DecodeError(f"vehicles claim {int(counts.sum())} points, the frame holds {K}")
    vx, vy = h.velocity_q
    if vx == VELOCITY_UNKNOWN:
        velocity = np.full(2, np.nan)
    else:
        velocity = np.array([vx, vy], np.float64) / 100.0
    boxes = np.zeros((V, 6), np.float32)
    boxes[:, :4] = veh["box"].astype(np.float32) / 2.0
    boxes[:, 4] = veh["score"].astype(np.float32) / 255.0
    boxes[:, 5] = veh["depth"].astype(np.float32) / 100.0
    points = np.zeros((K, 5), np.float32)
    points[:, :3] = pts["xyz"].astype(np.float32) / 100.0
    points[:, 3] = pts["doppler"].astype(np.float32) / 100.0
    points[:, 4] = pts["snr"].astype(np.float32) / 2.0
    frame = SharedFrame(
        sender=h.sender, seq=h.seq, stamp=h.stamp, radar_height=h.radar_height,
        ego_velocity=velocity,
        vehicle_points=points,
        vehicle_index=np.repeat(np.arange(V, dtype=np.int32), counts),
        vehicle_boxes=boxes,
        vehicle_box_index=veh["box_index"].astype(np.int32),
        vehicle_centers=veh["centre"].astype(np.float32) / 100.0,
        vehicle_features=veh["descriptor"].astype(np.float32) / 255.0,
        background=bgr["xyz"].astype(np.float32).reshape(B, 3) / 100.0,
        moving=mov["xy"].astype(np.float32).reshape(h.moving, 2) / 100.0,
    )
    check_range(frame, limits)
    return frame


def check_range(frame: SharedFrame, limits: Limits = LIMITS) -> None:
    """OverCaps when a point, centre or box depth of `frame` lies beyond `limits.max_range_m`."""
    reach = limits.max_range_m + 0.005  # half a quantisation step
    for name, a in (("vehicle points", frame.vehicle_points[:, :3]), ("vehicle centres", frame.vehicle_centers),
                    ("background", frame.background), ("moving points", frame.moving),
                    ("box depths", frame.vehicle_boxes[:, 5])):
        if a.size and float(np.abs(a).max()) > reach:
            raise OverCaps(f"{name} beyond the radar's range ({limits.max_range_m:g} m)")
