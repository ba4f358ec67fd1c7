"""TLV message types of the TI mmWave UART output (ti_formats.md section 1a).

One frozen dataclass per TLV payload, each with ``from_bytes(payload)`` and ``to_bytes()``
(payload only, without the 8-byte TLV header). Point lists and arrays decode with one
``np.frombuffer`` over a structured dtype (no per-point loop). Two registries map TLV type
numbers to classes: `OOB_TLVS` for the out-of-box demo / radar_toolbox 40-byte format and
`PC3D_TLVS` for the Industrial-Toolbox 3D People Counting 48-byte format (where 6/7/8 mean
compressed points / target list / target index). Types not in a registry decode to `RawTlv`.

Equality of two messages is equality of their type and payload bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar

import numpy as np

from mmatch.errors import DecodeError


class TlvType(IntEnum):
    """TLV type numbers (OOB demo SDK 1.x-3.x, L-SDK, radar_toolbox)."""

    DETECTED_POINTS = 1
    RANGE_PROFILE = 2
    NOISE_PROFILE = 3
    AZIMUTH_STATIC_HEAT_MAP = 4
    RANGE_DOPPLER_HEAT_MAP = 5
    STATS = 6
    DETECTED_POINTS_SIDE_INFO = 7
    AZIMUTH_ELEVATION_STATIC_HEAT_MAP = 8
    TEMPERATURE_STATS = 9
    EXT_DETECTED_POINTS = 301
    TARGET_LIST_3D = 1010
    TARGET_INDEX = 1011
    TARGET_HEIGHT = 1012
    COMPRESSED_POINTS = 1020
    PRESENCE_INDICATION = 1021


class Pc3dTlvType(IntEnum):
    """TLV type numbers of the 48-byte Industrial-Toolbox 3D People Counting format."""

    COMPRESSED_POINTS = 6
    TARGET_LIST_3D = 7
    TARGET_INDEX = 8


# ---- structured dtypes (little-endian, packed) -------------------------------------------
POINT_F32 = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("v", "<f4")])
POINT_Q = np.dtype([("range_idx", "<u2"), ("doppler_idx", "<i2"), ("peak_val", "<u2"),
                    ("x", "<i2"), ("y", "<i2"), ("z", "<i2")])
SIDE_INFO = np.dtype([("snr", "<i2"), ("noise", "<i2")])
EXT_POINT = np.dtype([("x", "<i2"), ("y", "<i2"), ("z", "<i2"), ("doppler", "<i2"),
                      ("snr", "u1"), ("noise", "u1")])
COMPRESSED_POINT = np.dtype([("elevation", "i1"), ("azimuth", "i1"), ("doppler", "<i2"),
                             ("range", "<u2"), ("snr", "<u2")])
TARGET_3D = np.dtype([("tid", "<u4"), ("pos", "<f4", (3,)), ("vel", "<f4", (3,)),
                      ("acc", "<f4", (3,)), ("ec", "<f4", (16,)), ("g", "<f4"),
                      ("confidence", "<f4")])
TARGET_2D = np.dtype([("tid", "<u4"), ("pos", "<f4", (2,)), ("vel", "<f4", (2,)),
                      ("acc", "<f4", (2,)), ("ec", "<f4", (9,)), ("g", "<f4"),
                      ("confidence", "<f4")])
TARGET_HEIGHT = np.dtype([("tid", "<u4"), ("max_z", "<f4"), ("min_z", "<f4")])
CMPLX16 = np.dtype([("imag", "<i2"), ("real", "<i2")])

assert POINT_F32.itemsize == 16 and POINT_Q.itemsize == 12 and EXT_POINT.itemsize == 10
assert COMPRESSED_POINT.itemsize == 8 and TARGET_3D.itemsize == 112 and TARGET_2D.itemsize == 72


def _records(payload: bytes | memoryview, dtype: np.dtype, name: str, offset: int = 0) -> np.ndarray:
    """`payload[offset:]` as a structured array; the size must be a whole multiple.

    Immutable `bytes` are viewed (read-only array, no copy); anything else is copied.
    """
    n, rest = divmod(len(payload) - offset, dtype.itemsize)
    if rest or n < 0:
        raise DecodeError(f"{name}: payload of {len(payload)} B is not {offset} + k*{dtype.itemsize} B")
    arr = np.frombuffer(payload, dtype=dtype, count=n, offset=offset)
    return arr if isinstance(payload, bytes) else arr.copy()


class TlvMessage:
    """Base of all TLV payloads: ``type``, ``from_bytes(payload)``, ``to_bytes()``."""

    type: ClassVar[int]

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> TlvMessage:  # pragma: no cover
        raise NotImplementedError

    def to_bytes(self) -> bytes:  # pragma: no cover
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TlvMessage):
            return NotImplemented
        return type(self) is type(other) and self.type == other.type and self.to_bytes() == other.to_bytes()

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class RawTlv(TlvMessage):
    """A TLV kept as raw bytes (unknown type, or a type outside the registry in use)."""

    tlv_type: int
    payload: bytes

    @property
    def type(self) -> int:  # type: ignore[override]
        return self.tlv_type

    def to_bytes(self) -> bytes:
        return bytes(self.payload)


@dataclass(frozen=True, eq=False)
class DetectedPoints(TlvMessage):
    """TLV 1, SDK 3.x: N x {f32 x, y, z (m), velocity (m/s, radial)}; `points` is POINT_F32."""

    type: ClassVar[int] = TlvType.DETECTED_POINTS
    points: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> DetectedPoints:
        return cls(_records(payload, POINT_F32, "TLV 1 (float)"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.points, dtype=POINT_F32).tobytes()


@dataclass(frozen=True, eq=False)
class DetectedPointsQ(TlvMessage):
    """TLV 1, SDK 1.x/2.x: descriptor {u16 numDetectedObj, u16 xyzQFormat} + N x POINT_Q.

    Coordinates in metres are ``raw / 2**q_format``; doppler_idx is signed Doppler bins;
    peak_val is the CFAR peak magnitude (not an SNR).
    """

    type: ClassVar[int] = TlvType.DETECTED_POINTS
    q_format: int
    objects: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> DetectedPointsQ:
        if len(payload) < 4:
            raise DecodeError(f"TLV 1 (Q-format): payload of {len(payload)} B has no descriptor")
        n, q = struct.unpack_from("<HH", payload, 0)
        objects = _records(payload, POINT_Q, "TLV 1 (Q-format)", offset=4)
        if len(objects) != n:
            raise DecodeError(f"TLV 1 (Q-format): descriptor says {n} objects, payload holds {len(objects)}")
        if q > 15:
            raise DecodeError(f"TLV 1 (Q-format): xyzQFormat {q} > 15")
        return cls(q, objects)

    def to_bytes(self) -> bytes:
        objs = np.ascontiguousarray(self.objects, dtype=POINT_Q)
        return struct.pack("<HH", len(objs), self.q_format) + objs.tobytes()

    def xyz_m(self) -> np.ndarray:
        """float32 (N, 3) x, y, z in metres."""
        o = self.objects
        xyz = np.stack([o["x"], o["y"], o["z"]], axis=1).astype(np.float32)
        return xyz / np.float32(1 << self.q_format)


@dataclass(frozen=True, eq=False)
class _U16Array(TlvMessage):
    values: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> _U16Array:
        return cls(_records(payload, np.dtype("<u2"), f"TLV {cls.type}"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.values, dtype="<u2").tobytes()


@dataclass(frozen=True, eq=False)
class RangeProfile(_U16Array):
    """TLV 2: numRangeBins x u16, Q9 log2 magnitude summed over virtual antennas."""

    type: ClassVar[int] = TlvType.RANGE_PROFILE


@dataclass(frozen=True, eq=False)
class NoiseProfile(_U16Array):
    """TLV 3: like TLV 2, at the maximum Doppler bin."""

    type: ClassVar[int] = TlvType.NOISE_PROFILE


@dataclass(frozen=True, eq=False)
class RangeDopplerHeatMap(_U16Array):
    """TLV 5: numRangeBins x numDopplerBins u16, range-major (reshape with the cfg)."""

    type: ClassVar[int] = TlvType.RANGE_DOPPLER_HEAT_MAP


@dataclass(frozen=True, eq=False)
class _Cmplx16Array(TlvMessage):
    values: np.ndarray  # CMPLX16 records, range-major, numVirtAnt per range bin

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> _Cmplx16Array:
        return cls(_records(payload, CMPLX16, f"TLV {cls.type}"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.values, dtype=CMPLX16).tobytes()

    def complex(self, num_virtual_antennas: int) -> np.ndarray:
        """complex64 (numRangeBins, numVirtAnt)."""
        z = self.values["real"].astype(np.float32) + 1j * self.values["imag"].astype(np.float32)
        return z.astype(np.complex64).reshape(-1, num_virtual_antennas)


@dataclass(frozen=True, eq=False)
class AzimuthStaticHeatMap(_Cmplx16Array):
    """TLV 4: numRangeBins x numVirtAnt x {i16 imag, i16 real}."""

    type: ClassVar[int] = TlvType.AZIMUTH_STATIC_HEAT_MAP


@dataclass(frozen=True, eq=False)
class AzimuthElevationStaticHeatMap(_Cmplx16Array):
    """TLV 8 (xWR18xx/68xx 3D): same element layout as TLV 4."""

    type: ClassVar[int] = TlvType.AZIMUTH_ELEVATION_STATIC_HEAT_MAP


_STATS_FIELDS = ("inter_frame_processing_time", "transmit_output_time",
                 "inter_frame_processing_margin", "inter_chirp_processing_margin",
                 "active_frame_cpu_load", "inter_frame_cpu_load")


@dataclass(frozen=True, eq=False)
class Stats(TlvMessage):
    """TLV 6: six u32 (times in us, loads in %)."""

    type: ClassVar[int] = TlvType.STATS
    inter_frame_processing_time: int = 0
    transmit_output_time: int = 0
    inter_frame_processing_margin: int = 0
    inter_chirp_processing_margin: int = 0
    active_frame_cpu_load: int = 0
    inter_frame_cpu_load: int = 0

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> Stats:
        if len(payload) != 24:
            raise DecodeError(f"TLV 6: payload of {len(payload)} B, expected 24")
        return cls(*struct.unpack("<6I", payload))

    def to_bytes(self) -> bytes:
        return struct.pack("<6I", *(getattr(self, f) for f in _STATS_FIELDS))


@dataclass(frozen=True, eq=False)
class SideInfo(TlvMessage):
    """TLV 7: N x {i16 snr, i16 noise}, units 0.1 dB (signed, as the doxygen types them)."""

    type: ClassVar[int] = TlvType.DETECTED_POINTS_SIDE_INFO
    info: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> SideInfo:
        return cls(_records(payload, SIDE_INFO, "TLV 7"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.info, dtype=SIDE_INFO).tobytes()

    def snr_db(self) -> np.ndarray:
        return self.info["snr"].astype(np.float32) * np.float32(0.1)


@dataclass(frozen=True, eq=False)
class TemperatureStats(TlvMessage):
    """TLV 9: i32 tempReportValid (0 = valid), u32 time (ms), 10 x i16 temperatures (deg C):
    Rx0..3, Tx0..2, PM, Dig0, Dig1."""

    type: ClassVar[int] = TlvType.TEMPERATURE_STATS
    report_valid: int
    time_ms: int
    temperatures: tuple[int, ...]

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> TemperatureStats:
        if len(payload) != 28:
            raise DecodeError(f"TLV 9: payload of {len(payload)} B, expected 28")
        v = struct.unpack("<iI10h", payload)
        return cls(v[0], v[1], tuple(v[2:]))

    def to_bytes(self) -> bytes:
        return struct.pack("<iI10h", self.report_valid, self.time_ms, *self.temperatures)


@dataclass(frozen=True, eq=False)
class ExtDetectedPoints(TlvMessage):
    """TLV 301 (xWRL6432 L-SDK): units {f32 xyz (m), doppler (m/s), snr (dB), noise (dB);
    i16 numDetPointsMajor, numDetPointsMinor} + N x EXT_POINT (value = raw x unit)."""

    type: ClassVar[int] = TlvType.EXT_DETECTED_POINTS
    units: tuple[float, float, float, float]
    num_major: int
    num_minor: int
    points: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> ExtDetectedPoints:
        if len(payload) < 20:
            raise DecodeError(f"TLV 301: payload of {len(payload)} B, shorter than its 20-B unit")
        *units, major, minor = struct.unpack_from("<4f2h", payload, 0)
        pts = _records(payload, EXT_POINT, "TLV 301", offset=20)
        return cls(tuple(units), major, minor, pts)

    def to_bytes(self) -> bytes:
        return (struct.pack("<4f2h", *self.units, self.num_major, self.num_minor)
                + np.ascontiguousarray(self.points, dtype=EXT_POINT).tobytes())


@dataclass(frozen=True, eq=False)
class TargetList(TlvMessage):
    """TLV 1010 (and 7 in the 48-B format): tracks, 112-B 3D records `'I27f'` (TARGET_3D)
    or 72-B 2D records `'I17f'` (TARGET_2D) when the length only fits those."""

    type: ClassVar[int] = TlvType.TARGET_LIST_3D
    targets: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> TargetList:
        n = len(payload)
        dtype = TARGET_3D if n % TARGET_3D.itemsize == 0 else TARGET_2D
        return cls(_records(payload, dtype, f"TLV {cls.type} (target list)"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.targets).tobytes()


@dataclass(frozen=True, eq=False)
class TargetIndex(TlvMessage):
    """TLV 1011 (and 8 in the 48-B format): u8 track id per point of the previous frame;
    values >= 253 mean "not associated"."""

    type: ClassVar[int] = TlvType.TARGET_INDEX
    indices: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> TargetIndex:
        return cls(_records(payload, np.dtype(np.uint8), f"TLV {cls.type}"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.indices, dtype=np.uint8).tobytes()


@dataclass(frozen=True, eq=False)
class TargetHeight(TlvMessage):
    """TLV 1012: N x {u32 tid, f32 maxZ, f32 minZ} (m)."""

    type: ClassVar[int] = TlvType.TARGET_HEIGHT
    heights: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> TargetHeight:
        return cls(_records(payload, TARGET_HEIGHT, "TLV 1012"))

    def to_bytes(self) -> bytes:
        return np.ascontiguousarray(self.heights, dtype=TARGET_HEIGHT).tobytes()


@dataclass(frozen=True, eq=False)
class CompressedPoints(TlvMessage):
    """TLV 1020 (and 6 in the 48-B format): pointUnit {f32 elevation (rad), azimuth (rad),
    doppler (m/s), range (m), snr (linear ratio)} + N x COMPRESSED_POINT (value = raw x unit)."""

    type: ClassVar[int] = TlvType.COMPRESSED_POINTS
    units: tuple[float, float, float, float, float]
    points: np.ndarray

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> CompressedPoints:
        if len(payload) < 20:
            raise DecodeError(f"TLV {cls.type}: payload of {len(payload)} B, shorter than its 20-B unit")
        units = struct.unpack_from("<5f", payload, 0)
        return cls(units, _records(payload, COMPRESSED_POINT, f"TLV {cls.type}", offset=20))

    def to_bytes(self) -> bytes:
        return (struct.pack("<5f", *self.units)
                + np.ascontiguousarray(self.points, dtype=COMPRESSED_POINT).tobytes())


@dataclass(frozen=True, eq=False)
class PresenceIndication(TlvMessage):
    """TLV 1021: u32 presence flag."""

    type: ClassVar[int] = TlvType.PRESENCE_INDICATION
    present: int

    @classmethod
    def from_bytes(cls, payload: bytes | memoryview) -> PresenceIndication:
        if len(payload) != 4:
            raise DecodeError(f"TLV 1021: payload of {len(payload)} B, expected 4")
        return cls(struct.unpack("<I", payload)[0])

    def to_bytes(self) -> bytes:
        return struct.pack("<I", self.present)


# 48-byte people-counting variants: same payloads, other type numbers.
@dataclass(frozen=True, eq=False)
class Pc3dCompressedPoints(CompressedPoints):
    """TLV 6 of the 48-B people-counting format (payload of TLV 1020)."""

    type: ClassVar[int] = Pc3dTlvType.COMPRESSED_POINTS


@dataclass(frozen=True, eq=False)
class Pc3dTargetList(TargetList):
    """TLV 7 of the 48-B people-counting format (payload of TLV 1010)."""

    type: ClassVar[int] = Pc3dTlvType.TARGET_LIST_3D


@dataclass(frozen=True, eq=False)
class Pc3dTargetIndex(TargetIndex):
    """TLV 8 of the 48-B people-counting format (payload of TLV 1011)."""

    type: ClassVar[int] = Pc3dTlvType.TARGET_INDEX


# type -> class. TLV 1 is resolved by version (float for SDK >= 3, Q-format below).
OOB_TLVS: dict[int, type[TlvMessage]] = {
    cls.type: cls for cls in (
        RangeProfile, NoiseProfile, AzimuthStaticHeatMap, RangeDopplerHeatMap, Stats, SideInfo,
        AzimuthElevationStaticHeatMap, TemperatureStats, ExtDetectedPoints, TargetList,
        TargetIndex, TargetHeight, CompressedPoints, PresenceIndication)
}
PC3D_TLVS: dict[int, type[TlvMessage]] = {
    cls.type: cls for cls in (Pc3dCompressedPoints, Pc3dTargetList, Pc3dTargetIndex)
}

