"""DCA1000EVM wire records: UDP command/response (port 4096) and raw data packets (port 4098).

Layouts from ti_formats.md section 1b (TI DCA1000 CLI source). All fields little-endian.

Command:  u16 0xA55A | u16 cmd | u16 data size | data | u16 0xEEAA
Response: u16 0xA55A | u16 cmd | u16 status (0 = success) | u16 0xEEAA          (8 bytes)
Data:     u32 sequence number (from 1) | u48 bytes sent before this packet | payload (<= 1456 B)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from mmatch.errors import DecodeError

HEADER = 0xA55A
FOOTER = 0xEEAA
CONFIG_PORT = 4096
DATA_PORT = 4098
DATA_HEADER_BYTES = 10
MAX_PAYLOAD_BYTES = 1456
"""Largest raw-mode payload (PAYLOAD_BYTES_PER_PACKET); datagrams are at most 1466 bytes."""
RESPONSE_BYTES = 8

_CMD_HEAD = struct.Struct("<HHH")
_RESPONSE = struct.Struct("<HHHH")
_DATA_HEAD = struct.Struct("<IIH")  # seq, byte count low 32 bits, byte count high 16 bits


class Cmd(IntEnum):
    """DCA1000 command codes."""

    RESET_FPGA = 0x01
    RESET_AR_DEV = 0x02
    CONFIG_FPGA_GEN = 0x03
    CONFIG_EEPROM = 0x04
    RECORD_START = 0x05
    RECORD_STOP = 0x06
    PLAYBACK_START = 0x07
    PLAYBACK_STOP = 0x08
    SYSTEM_CONNECT = 0x09
    SYSTEM_ERROR = 0x0A
    CONFIG_PACKET_DATA = 0x0B
    CONFIG_DATA_MODE_AR_DEV = 0x0C
    INIT_FPGA_PLAYBACK = 0x0D
    READ_FPGA_VERSION = 0x0E


class LogMode(IntEnum):
    RAW = 1
    MULTI = 2


class LvdsMode(IntEnum):
    """Number of LVDS lanes: 4 for AR1243/AWR2243, 2 for xWR16xx/18xx/68xx."""

    FOUR_LANE = 1
    TWO_LANE = 2


class TransferMode(IntEnum):
    CAPTURE = 1
    PLAYBACK = 2


class CaptureMode(IntEnum):
    SD_CARD = 1
    ETHERNET = 2


class DataFormat(IntEnum):
    BITS_12 = 1
    BITS_14 = 2
    BITS_16 = 3


@dataclass(frozen=True)
class CommandPacket:
    """One command to the DCA1000 (host -> FPGA, UDP port 4096)."""

    cmd: int
    data: bytes = b""

    def to_bytes(self) -> bytes:
        return (
            _CMD_HEAD.pack(HEADER, int(self.cmd), len(self.data))
            + bytes(self.data)
            + FOOTER.to_bytes(2, "little")
        )

    @classmethod
    def from_bytes(cls, buf: bytes) -> "CommandPacket":
        """Decode a command datagram; raises DecodeError on a bad header, footer or size."""
        if len(buf) < 8:
            raise DecodeError(f"command packet of {len(buf)} bytes is shorter than 8")
        header, cmd, size = _CMD_HEAD.unpack_from(buf, 0)
        if header != HEADER:
            raise DecodeError(f"command header 0x{header:04X} != 0x{HEADER:04X}")
        if len(buf) != 8 + size:
            raise DecodeError(f"command data size {size} does not match a {len(buf)}-byte datagram")
        footer = int.from_bytes(buf[6 + size : 8 + size], "little")
        if footer != FOOTER:
            raise DecodeError(f"command footer 0x{footer:04X} != 0x{FOOTER:04X}")
        return cls(cmd, bytes(buf[6 : 6 + size]))


@dataclass(frozen=True)
class ResponsePacket:
    """The 8-byte answer to a command (FPGA -> host); status 0 = success.

    For READ_FPGA_VERSION the status field carries the version bits instead.
    """

    cmd: int
    status: int

    def to_bytes(self) -> bytes:
        return _RESPONSE.pack(HEADER, int(self.cmd), self.status, FOOTER)

    @classmethod
    def from_bytes(cls, buf: bytes) -> "ResponsePacket":
        if len(buf) != RESPONSE_BYTES:
            raise DecodeError(f"response of {len(buf)} bytes, expected {RESPONSE_BYTES}")
        header, cmd, status, footer = _RESPONSE.unpack(buf)
        if header != HEADER or footer != FOOTER:
            raise DecodeError(f"response header/footer 0x{header:04X}/0x{footer:04X} are wrong")
        return cls(cmd, status)


@dataclass(frozen=True)
class FpgaConfig:
    """CONFIG_FPGA_GEN payload (6 x u8). Defaults are the AWR2243 raw 4-lane Ethernet capture."""

    log_mode: LogMode = LogMode.RAW
    lvds_mode: LvdsMode = LvdsMode.FOUR_LANE
    transfer_mode: TransferMode = TransferMode.CAPTURE
    capture_mode: CaptureMode = CaptureMode.ETHERNET
    data_format: DataFormat = DataFormat.BITS_16
    lvds_timeout: int = 30

    def to_bytes(self) -> bytes:
        return bytes(
            [
                int(self.log_mode),
                int(self.lvds_mode),
                int(self.transfer_mode),
                int(self.capture_mode),
                int(self.data_format),
                int(self.lvds_timeout),
            ]
        )

    @classmethod
    def from_bytes(cls, buf: bytes) -> "FpgaConfig":
        if len(buf) != 6:
            raise DecodeError(f"FPGA config payload of {len(buf)} bytes, expected 6")
        try:
            return cls(
                LogMode(buf[0]),
                LvdsMode(buf[1]),
                TransferMode(buf[2]),
                CaptureMode(buf[3]),
                DataFormat(buf[4]),
                buf[5],
            )
        except ValueError as exc:
            raise DecodeError(
                f"FPGA config payload {bytes(buf).hex()} has an invalid field: {exc}"
            ) from exc


@dataclass(frozen=True)
class PacketConfig:
    """CONFIG_PACKET_DATA payload: datagram size (bytes) and inter-packet delay (us).

    On the wire the delay is in 8-ns FPGA clocks (`delay_us * 1000 / 8`), then a reserved u16 0.
    """

    packet_bytes: int = 1470
    delay_us: float = 25.0

    def to_bytes(self) -> bytes:
        clocks = int(round(self.delay_us * 1000 / 8))
        if not 0 <= clocks <= 0xFFFF:
            raise ValueError(
                f"packet delay {self.delay_us} us does not fit in 16 bits of 8-ns clocks"
            )
        return struct.pack("<HHH", self.packet_bytes, clocks, 0)

    @classmethod
    def from_bytes(cls, buf: bytes) -> "PacketConfig":
        if len(buf) != 6:
            raise DecodeError(f"packet config payload of {len(buf)} bytes, expected 6")
        size, clocks, _ = struct.unpack("<HHH", buf)
        return cls(size, clocks * 8 / 1000)


@dataclass(frozen=True)
class FpgaVersion:
    """READ_FPGA_VERSION status bits: major (7 bits), minor (7 bits), bit 14 = playback bitfile."""

    major: int
    minor: int
    playback: bool

    @classmethod
    def from_status(cls, status: int) -> "FpgaVersion":
        return cls(status & 0x7F, (status >> 7) & 0x7F, bool(status & 0x4000))

    def to_status(self) -> int:
        return (self.major & 0x7F) | ((self.minor & 0x7F) << 7) | (0x4000 if self.playback else 0)

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}{' (playback)' if self.playback else ''}"


@dataclass(frozen=True)
class DataPacketHeader:
    """Raw-mode data packet header: sequence number (from 1) and bytes sent before this packet."""

    seq: int
    byte_count: int

    def to_bytes(self) -> bytes:
        return _DATA_HEAD.pack(self.seq, self.byte_count & 0xFFFFFFFF, self.byte_count >> 32)

    @classmethod
    def from_bytes(cls, buf: bytes) -> "DataPacketHeader":
        if len(buf) < DATA_HEADER_BYTES:
            raise DecodeError(f"data packet of {len(buf)} bytes is shorter than its 10-byte header")
        seq, lo, hi = _DATA_HEAD.unpack_from(buf, 0)
        return cls(seq, lo | (hi << 32))


def data_packet(seq: int, byte_count: int, payload: bytes) -> bytes:
    """A complete raw-mode data datagram."""
    return _DATA_HEAD.pack(seq, byte_count & 0xFFFFFFFF, byte_count >> 32) + bytes(payload)


unpack_data_header = _DATA_HEAD.unpack_from
"""Fast path: `seq, lo, hi = unpack_data_header(buf)`; byte count = lo | hi << 32."""
