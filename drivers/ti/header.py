"""TI UART frame headers: 36-, 40- and 48-byte variants (ti_formats.md section 1a).

| format | header | who sends it |
|---|---|---|
| `H36` | magic, version, totalPacketLen, platform, frameNumber, timeCpuCycles, numDetectedObj, numTLVs | SDK 1.x/2.x xWR14xx |
| `H40` | H36 + subFrameNumber | SDK 2.x/3.x all chips, SDK 1.x xWR16xx, radar_toolbox labs |
| `H48` | magic, version, totalPacketLen, platform, frameNumber, subFrameNumber, chirpProcessingMargin, frameProcessingMargin, trackProcessTime, uartSentTime, u16 numTLVs, u16 checksum | Industrial-Toolbox 4.x 3D People Counting |

Choice (the reference's robust rule): ``platform & 0xFFFF == 0x1443`` and version major < 3
-> H36; else H48 if the header checksum holds (16-bit one's-complement sum of its 24
words == 0xFFFF); else H40.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum

MAGIC = bytes((0x02, 0x01, 0x04, 0x03, 0x06, 0x05, 0x08, 0x07))
"""Magic word: uint16 {0x0102, 0x0304, 0x0506, 0x0708} little-endian."""

PLATFORM_XWR14XX = 0x1443


class HeaderFormat(str, Enum):
    H36 = "h36"
    H40 = "h40"
    H48 = "h48"

    @property
    def size(self) -> int:
        return _SIZES[self]


_SIZES = {HeaderFormat.H36: 36, HeaderFormat.H40: 40, HeaderFormat.H48: 48}
_S36 = struct.Struct("<8s7I")
_S40 = struct.Struct("<8s8I")
_S48 = struct.Struct("<8s9I2H")


def ones_complement_sum16(data: bytes | bytearray | memoryview, offset: int = 0, nwords: int = 24) -> int:
    """16-bit one's-complement sum of `nwords` little-endian uint16 words."""
    s = sum(struct.unpack_from(f"<{nwords}H", data, offset))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return s


def pc3d_checksum_ok(buf: bytes | bytearray | memoryview, offset: int) -> bool:
    """True when the 48 bytes at `offset` form a people-counting header with a valid checksum."""
    return ones_complement_sum16(buf, offset, 24) == 0xFFFF


def version_major(version: int) -> int:
    return (version >> 24) & 0xFF


def version_string(version: int) -> str:
    """'3.5.0.4' from 0x03050004."""
    return ".".join(str((version >> s) & 0xFF) for s in (24, 16, 8, 0))


def candidate_formats(buf: bytes | bytearray, offset: int, avail: int) -> list[HeaderFormat]:
    """Header formats the bytes at `offset` may hold, most likely first.

    `avail` is the number of bytes available from `offset` (>= 20 so version and platform
    are readable). H48 is offered only when 48 bytes are there and the checksum holds.
    """
    version, _, platform = struct.unpack_from("<3I", buf, offset + 8)
    if platform & 0xFFFF == PLATFORM_XWR14XX and version_major(version) < 3:
        return [HeaderFormat.H36]
    if avail >= 48 and pc3d_checksum_ok(buf, offset):
        return [HeaderFormat.H48, HeaderFormat.H40]
    return [HeaderFormat.H40]


@dataclass(frozen=True)
class FrameHeader:
    """One frame header; fields absent from a format stay 0. Times in CPU cycles or us as
    the device reports them (timeCpuCycles: R4F/DSP cycles; people-counting margins and
    times: us)."""

    fmt: HeaderFormat
    version: int
    total_packet_len: int
    platform: int
    frame_number: int
    num_tlvs: int
    time_cpu_cycles: int = 0
    num_detected_obj: int = 0
    sub_frame_number: int = 0
    chirp_processing_margin: int = 0
    frame_processing_margin: int = 0
    track_process_time: int = 0
    uart_sent_time: int = 0
    checksum: int = 0

    @property
    def size(self) -> int:
        return self.fmt.size

    @classmethod
    def from_bytes(cls, buf: bytes | bytearray | memoryview, offset: int, fmt: HeaderFormat) -> FrameHeader:
        """Unpack a header of format `fmt` at `offset` (the caller checked the length)."""
        if fmt is HeaderFormat.H36:
            _, ver, total, plat, fn, cyc, nobj, ntlv = _S36.unpack_from(buf, offset)
            return cls(fmt, ver, total, plat, fn, ntlv, time_cpu_cycles=cyc, num_detected_obj=nobj)
        if fmt is HeaderFormat.H40:
            _, ver, total, plat, fn, cyc, nobj, ntlv, sub = _S40.unpack_from(buf, offset)
            return cls(fmt, ver, total, plat, fn, ntlv, time_cpu_cycles=cyc, num_detected_obj=nobj,
                       sub_frame_number=sub)
        _, ver, total, plat, fn, sub, cpm, fpm, tpt, ust, ntlv, cks = _S48.unpack_from(buf, offset)
        return cls(fmt, ver, total, plat, fn, ntlv, sub_frame_number=sub, chirp_processing_margin=cpm,
                   frame_processing_margin=fpm, track_process_time=tpt, uart_sent_time=ust,
                   checksum=cks)

    def to_bytes(self) -> bytes:
        """Pack the header; for H48 the checksum is computed (the field's value is ignored)."""
        if self.fmt is HeaderFormat.H36:
            return _S36.pack(MAGIC, self.version, self.total_packet_len, self.platform,
                             self.frame_number, self.time_cpu_cycles, self.num_detected_obj,
                             self.num_tlvs)
        if self.fmt is HeaderFormat.H40:
            return _S40.pack(MAGIC, self.version, self.total_packet_len, self.platform,
                             self.frame_number, self.time_cpu_cycles, self.num_detected_obj,
                             self.num_tlvs, self.sub_frame_number)
        raw = _S48.pack(MAGIC, self.version, self.total_packet_len, self.platform, self.frame_number,
                        self.sub_frame_number, self.chirp_processing_margin,
                        self.frame_processing_margin, self.track_process_time, self.uart_sent_time,
                        self.num_tlvs, 0)
        cks = ~ones_complement_sum16(raw, 0, 23) & 0xFFFF
        return raw[:46] + struct.pack("<H", cks)

    def device_fields(self) -> dict:
        """The device timing/identity fields, TI names, for `RadarFrame.device`."""
        d = {"format": self.fmt.value, "version": version_string(self.version),
             "platform": f"{self.platform:#x}", "frameNumber": self.frame_number,
             "numTLVs": self.num_tlvs, "subFrameNumber": self.sub_frame_number}
        if self.fmt is HeaderFormat.H48:
            d.update(chirpProcessingMargin=self.chirp_processing_margin,
                     frameProcessingMargin=self.frame_processing_margin,
                     trackProcessTime=self.track_process_time, uartSentTime=self.uart_sent_time)
        else:
            d.update(timeCpuCycles=self.time_cpu_cycles, numDetectedObj=self.num_detected_obj)
        return d
