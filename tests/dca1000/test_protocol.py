"""Wire records of the DCA1000 protocol against the bytes in ti_formats.md section 1b."""

from __future__ import annotations

import pytest

from mmatch.drivers.dca1000.protocol import (
    Cmd,
    CommandPacket,
    DataPacketHeader,
    FpgaConfig,
    FpgaVersion,
    LvdsMode,
    PacketConfig,
    ResponsePacket,
    data_packet,
)
from mmatch.errors import DecodeError


def test_awr2243_fpga_config_bytes_match_ti():
    pkt = CommandPacket(Cmd.CONFIG_FPGA_GEN, FpgaConfig().to_bytes()).to_bytes()
    assert pkt == bytes.fromhex("5aa5 0300 0600 01 01 01 02 03 1e aaee")
    two_lane = FpgaConfig.from_bytes(bytes.fromhex("01020102031e"))
    assert two_lane.lvds_mode is LvdsMode.TWO_LANE and two_lane.to_bytes() == bytes.fromhex(
        "01020102031e"
    )


def test_packet_config_matches_openradar_bytes():
    # OpenRadar sends c0 05 35 0c 00 00: 1472-byte packets, 3125 clocks of 8 ns = 25 us
    assert PacketConfig(1472, 25.0).to_bytes() == bytes.fromhex("c005350c0000")
    assert PacketConfig.from_bytes(bytes.fromhex("c005350c0000")) == PacketConfig(1472, 25.0)


def test_openradar_bug_payload_is_not_an_fpga_config():
    # OpenRadar sent the packet-config payload with the FPGA-config code; it must not decode
    with pytest.raises(DecodeError):
        FpgaConfig.from_bytes(bytes.fromhex("c005350c0000"))


def test_command_roundtrip_and_errors():
    pkt = CommandPacket(Cmd.RECORD_START).to_bytes()
    assert pkt == bytes.fromhex("5aa505000000aaee")
    assert CommandPacket.from_bytes(pkt) == CommandPacket(Cmd.RECORD_START, b"")
    with pytest.raises(DecodeError, match="footer"):
        CommandPacket.from_bytes(pkt[:-1] + b"\x00")
    with pytest.raises(DecodeError, match="size"):
        CommandPacket.from_bytes(pkt + b"\x00")
    with pytest.raises(DecodeError, match="header"):
        CommandPacket.from_bytes(b"\x00" + pkt[1:])


def test_response_decode():
    r = ResponsePacket.from_bytes(bytes.fromhex("5aa509000000aaee"))
    assert (r.cmd, r.status) == (Cmd.SYSTEM_CONNECT, 0)
    assert ResponsePacket(Cmd.RECORD_STOP, 3).to_bytes() == bytes.fromhex("5aa506000300aaee")
    with pytest.raises(DecodeError):
        ResponsePacket.from_bytes(bytes.fromhex("5aa509000000aaef"))
    with pytest.raises(DecodeError):
        ResponsePacket.from_bytes(bytes.fromhex("5aa5090000"))


def test_data_header_u48_byte_count():
    big = (1 << 40) + 12345
    raw = data_packet(7, big, b"\x01\x02")
    assert raw[:4] == (7).to_bytes(4, "little") and raw[4:10] == big.to_bytes(6, "little")
    h = DataPacketHeader.from_bytes(raw)
    assert (h.seq, h.byte_count) == (7, big)
    assert h.to_bytes() == raw[:10]
    with pytest.raises(DecodeError):
        DataPacketHeader.from_bytes(raw[:9])


def test_fpga_version_bits():
    v = FpgaVersion.from_status(0x4000 | (5 << 7) | 2)
    assert (v.major, v.minor, v.playback) == (2, 5, True)
    assert v.to_status() == 0x4000 | (5 << 7) | 2
