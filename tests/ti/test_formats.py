"""Writer -> decoder fixtures for every format and TLV type, the known quirks, golden bytes."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from mmatch.drivers.ti.cfg import load_cfg
from mmatch.drivers.ti.decoder import NEED_MORE, OK, REJECT, decode_frame
from mmatch.drivers.ti.header import MAGIC, FrameHeader, HeaderFormat, pc3d_checksum_ok
from mmatch.drivers.ti.tlv import (
    OOB_TLVS, PC3D_TLVS, DetectedPoints, DetectedPointsQ, Pc3dCompressedPoints, RawTlv, SideInfo,
    Stats, TlvType)
from mmatch.drivers.ti.writer import (
    FORMATS, EncodeError, encode_frame, encode_packet, encode_stream, expected_points, point_tlvs)
from mmatch.errors import DecodeError

from .helpers import all_tlv_messages, golden_pc3d_frame, golden_sdk3_frame, make_points

CHIRP = load_cfg(Path(__file__).resolve().parents[2] / "cfg" / "radar" / "xwr18xx_vehicle_100m.cfg").chirp


def decode_ok(data: bytes, **kw):
    res = decode_frame(data, **kw)
    assert res.status == OK, (res.reason, res.detail)
    assert res.length == len(data)
    return res.packet


@pytest.mark.parametrize("fmt", sorted(FORMATS))
@pytest.mark.parametrize("n", [0, 1, 17, 300])
def test_points_roundtrip_every_format(fmt, n):
    pts = make_points(n, seed=n + 3)
    data = encode_frame(pts, 1234, fmt, chirp=CHIRP)
    pkt = decode_ok(data, chirp=CHIRP)
    hdr = pkt.header
    assert hdr.fmt is FORMATS[fmt].header
    assert hdr.frame_number == 1234 and hdr.total_packet_len == len(data)
    assert pkt.points.dtype == np.float32 and pkt.points.shape == (n, 5)
    np.testing.assert_array_equal(pkt.points, expected_points(pts, fmt, chirp=CHIRP))
    if fmt == "pc3d":
        assert len(data) == 48 + 8 + 20 + 8 * n  # unpadded, TLV length incl. header
    else:
        assert len(data) % 32 == 0


def test_sdk3_is_lossless_but_snr_in_tenths():
    pts = make_points(50, seed=9)
    pkt = decode_ok(encode_frame(pts, 1, "sdk3"))
    np.testing.assert_array_equal(pkt.points[:, :4], pts[:, :4])
    np.testing.assert_allclose(pkt.points[:, 4], pts[:, 4], atol=0.05 + 1e-6)


def test_qformat_quantisation_and_doppler_scaling():
    pts = make_points(40, seed=4, max_range=100.0)
    assert 64.0 < np.abs(pts[:, :3]).max() < 128.0
    pkt = decode_ok(encode_frame(pts, 1, "sdk2", chirp=CHIRP), chirp=CHIRP)
    q = pkt.tlvs[0].q_format
    assert isinstance(pkt.tlvs[0], DetectedPointsQ) and q == 8  # > 64 m needs Q8, not Q9
    np.testing.assert_allclose(pkt.points[:, :3], pts[:, :3], atol=0.5 / 2**q + 1e-6)
    np.testing.assert_allclose(pkt.points[:, 3], pts[:, 3], atol=CHIRP.doppler_resolution_mps / 2 + 1e-5)
    assert np.all(pkt.points[:, 4] == 0.0)  # Q-format carries no SNR
    # without a cfg the decoder cannot scale Doppler bins: 0.0, never raw bin numbers
    assert np.all(decode_ok(encode_frame(pts, 1, "sdk2", chirp=CHIRP)).points[:, 3] == 0.0)


def test_unsigned_doppler_indices_wrap():
    objs = np.zeros(2, DetectedPointsQ.from_bytes(struct.pack("<HH", 0, 9)).objects.dtype)
    objs["doppler_idx"] = [3, CHIRP.num_doppler_bins - 3]  # SDK 1.x xWR14xx sends 0..N-1
    data = encode_packet([DetectedPointsQ(9, objs)], 5, "xwr14xx", num_detected_obj=2)
    pkt = decode_ok(data, chirp=CHIRP)
    np.testing.assert_allclose(pkt.points[:, 3], [3 * CHIRP.doppler_resolution_mps,
                                                  -3 * CHIRP.doppler_resolution_mps], rtol=1e-6)


def test_compressed_spherical_conversion_independent():
    pts = make_points(30, seed=5)
    for fmt in ("toolbox", "pc3d"):
        pkt = decode_ok(encode_frame(pts, 3, fmt))
        c = pkt.tlvs[0]
        u = [float(x) for x in c.units]
        p = c.points
        el, az = p["elevation"] * u[0], p["azimuth"] * u[1]
        r = p["range"].astype(float) * u[3]
        ref = np.stack([r * np.cos(el) * np.sin(az), r * np.cos(el) * np.cos(az), r * np.sin(el),
                        p["doppler"] * u[2], 10 * np.log10(p["snr"] * u[4])], axis=1)
        np.testing.assert_allclose(pkt.points, ref, rtol=2e-6, atol=2e-5)
        # and close to the input: 0.01 rad at 60 m is 0.3 m
        np.testing.assert_allclose(pkt.points[:, :3], pts[:, :3], atol=0.45)
        np.testing.assert_allclose(pkt.points[:, 3], pts[:, 3], atol=0.0011)


def test_every_tlv_type_roundtrips_in_40_byte_format():
    msgs = all_tlv_messages()
    pts = make_points(6, seed=2)
    for fmt in ("sdk3", "toolbox"):
        data = encode_frame(pts, 77, fmt, extra_tlvs=msgs["oob"])
        pkt = decode_ok(data)
        extra = list(pkt.tlvs[len(point_tlvs(pts, fmt)):])
        assert extra == msgs["oob"]
        assert [type(m) for m in extra] == [type(m) for m in msgs["oob"]]
        kinds = {int(t.type) for t in pkt.tlvs}
        assert {2, 3, 4, 5, 6, 8, 9, 301, 1010, 1011, 1012, 1020, 1021, 10, 555} <= kinds
        assert sum(isinstance(t, RawTlv) for t in pkt.tlvs) == 2  # 10 and 555 kept raw
    assert set(OOB_TLVS) | {1} == {int(t) for t in TlvType}


def test_target_list_2d_and_side_info_messages():
    msgs = all_tlv_messages()
    pkt = decode_ok(encode_packet(msgs["target2d"] + msgs["side_info"], 1, "toolbox"))
    assert pkt.tlvs[0].targets.dtype.itemsize == 72 and pkt.tlvs[0] == msgs["target2d"][0]
    assert pkt.tlvs[1] == msgs["side_info"][0]


def test_pc3d_tlvs_6_7_8():
    msgs = all_tlv_messages()
    pts = make_points(12, seed=8)
    data = encode_frame(pts, 45, "pc3d", extra_tlvs=msgs["pc3d"])
    pkt = decode_ok(data)
    assert [int(t.type) for t in pkt.tlvs] == [6, 7, 8, 12]
    assert isinstance(pkt.tlvs[0], Pc3dCompressedPoints)
    assert list(pkt.tlvs[1:]) == msgs["pc3d"]
    assert set(PC3D_TLVS) == {6, 7, 8}
    # TLV lengths include the 8-byte TLV header in this format
    t1_len = struct.unpack_from("<I", data, 48 + 4)[0]
    assert t1_len == 8 + 20 + 8 * 12


def test_sdk33_quirk_zero_length_tlv1_no_tlv7():
    empty = np.zeros((0, 5), np.float32)
    data = encode_frame(empty, 265, "sdk3", empty_tlv1="zero_length")
    assert struct.unpack_from("<2I", data, 40) == (1, 0)  # TLV 1, length 0
    pkt = decode_ok(data)
    assert pkt.header.num_tlvs == 1 and pkt.header.num_detected_obj == 0
    assert isinstance(pkt.tlvs[0], DetectedPoints) and len(pkt.tlvs[0].points) == 0
    assert pkt.points.shape == (0, 5)
    omitted = decode_ok(encode_frame(empty, 266, "sdk3"))
    assert omitted.header.num_tlvs == 0 and omitted.points.shape == (0, 5)


def test_sdk3_without_side_info_has_snr_zero():
    pts = make_points(4, seed=1)
    pkt = decode_ok(encode_frame(pts, 1, "sdk3", side_info=False))
    assert pkt.header.num_tlvs == 1
    np.testing.assert_array_equal(pkt.points[:, :4], pts[:, :4])
    assert np.all(pkt.points[:, 4] == 0.0)


def test_padding_is_32_byte_multiple_with_less_than_32_pad():
    for n in range(0, 9):
        data = encode_frame(make_points(n, seed=n), 1, "sdk3")
        used = 40 + (8 + 16 * n + 8 + 4 * n if n else 0)
        assert len(data) % 32 == 0 and 0 <= len(data) - used < 32
        assert data[used:] == bytes(len(data) - used)


def test_golden_sdk3_bytes():
    golden = golden_sdk3_frame()
    pts = np.array([[1.0, 2.0, 0.5, -1.5, 12.5], [-3.0, 40.0, 0.0, 12.25, -0.5]], np.float32)
    assert encode_frame(pts, 7, "sdk3", noise_db=np.array([3.0, 3.1])) == golden
    pkt = decode_ok(golden)
    np.testing.assert_array_equal(pkt.points, np.array(
        [[1.0, 2.0, 0.5, -1.5, np.float32(125) * np.float32(0.1)],
         [-3.0, 40.0, 0.0, 12.25, np.float32(-5) * np.float32(0.1)]], np.float32))
    assert isinstance(pkt.tlvs[1], SideInfo) and pkt.tlvs[1].info["noise"].tolist() == [30, 31]
    assert pkt.header.device_fields()["version"] == "3.5.0.4"


def test_golden_pc3d_bytes_and_checksum():
    golden = golden_pc3d_frame()
    assert pc3d_checksum_ok(golden, 0)
    pkt = decode_ok(golden)
    h = pkt.header
    assert h.fmt is HeaderFormat.H48 and h.frame_number == 45 and h.num_tlvs == 1
    assert (h.chirp_processing_margin, h.frame_processing_margin, h.track_process_time,
            h.uart_sent_time) == (51, 7, 325, 5188)
    assert FrameHeader.from_bytes(golden, 0, HeaderFormat.H48).to_bytes() == golden[:48]
    r, el, az = 8000 * 0.00025, 5 * 0.01, -10 * 0.01
    np.testing.assert_allclose(pkt.points[0], [r * np.cos(el) * np.sin(az), r * np.cos(el) * np.cos(az),
                                               r * np.sin(el), 1000 * 0.00028, 10 * np.log10(500 * 0.04)],
                               rtol=1e-6)
    assert pkt.radar_frame(1.5).device["trackProcessTime"] == 325


def test_header_format_choice():
    pts = make_points(3)
    h14 = encode_frame(pts, 1, "xwr14xx")
    assert decode_ok(h14).header.fmt is HeaderFormat.H36
    # an xWR1443 claiming SDK 3 is read with the 40-byte header (robust rule)
    h14_v3 = encode_frame(pts, 1, "sdk3", platform=0xA1443)
    assert decode_ok(h14_v3).header.fmt is HeaderFormat.H40


def test_radar_frame_fields():
    pts = make_points(3)
    pkt = decode_ok(encode_frame(pts, 99, "sdk3", time_cpu_cycles=123456, sub_frame_number=1))
    rf = pkt.radar_frame(1000.25)
    assert rf.frame_number == 99 and rf.host_time == 1000.25 and rf.stamp == 1000.25
    assert rf.device["timeCpuCycles"] == 123456 and rf.device["subFrameNumber"] == 1
    assert rf.device["numDetectedObj"] == 3 and rf.device["platform"] == "0xa1843"


def test_decode_frame_statuses():
    data = encode_frame(make_points(10), 1, "sdk3")
    assert decode_frame(data[:-1], final=False).status == NEED_MORE
    assert decode_frame(data[:30], final=False).status == NEED_MORE
    r = decode_frame(data[:-1])
    assert r.status == REJECT and r.reason == "truncated"
    r = decode_frame(data[:-10] + MAGIC, final=False)
    assert r.status == REJECT and r.reason == "magic_inside_packet"
    # a magic word starting in the packet's last byte (one byte dropped before it)
    r = decode_frame(data[:-1] + MAGIC, final=False)
    assert r.status == REJECT and r.reason == "magic_inside_packet"
    # ... and while only its first bytes have arrived, the decoder waits
    assert decode_frame(data[:-1] + MAGIC[:3], final=False).status == NEED_MORE
    assert decode_frame(data, final=False).status == OK  # zero padding is no magic prefix
    two = data + data
    assert decode_frame(two, len(data)).status == OK


def test_tlv_messages_reject_bad_sizes():
    with pytest.raises(DecodeError):
        DetectedPoints.from_bytes(bytes(15))
    with pytest.raises(DecodeError):
        Stats.from_bytes(bytes(20))
    with pytest.raises(DecodeError):
        DetectedPointsQ.from_bytes(struct.pack("<HH", 2, 9) + bytes(12))
    assert Stats.from_bytes(Stats(1, 2, 3, 4, 5, 6).to_bytes()) == Stats(1, 2, 3, 4, 5, 6)


def test_writer_refuses_bad_input():
    with pytest.raises(EncodeError):
        encode_frame(np.zeros((3, 4), np.float32), 1)
    with pytest.raises(EncodeError):
        encode_frame(np.full((1, 5), np.nan, np.float32), 1)
    with pytest.raises(EncodeError, match="unknown TLV format"):
        encode_frame(np.zeros((1, 5), np.float32), 1, "sdk9")


def test_encode_stream_numbers_frames():
    frames = [make_points(k, seed=k) for k in range(5)]
    data = encode_stream(frames, "sdk3", first_frame=40)
    off, fns = 0, []
    while off < len(data):
        res = decode_frame(data, off)
        assert res.status == OK
        fns.append(res.packet.header.frame_number)
        off += res.length
    assert fns == [40, 41, 42, 43, 44]


def test_shapes_seen_in_real_recordings():
    """Sizes the reference reports from real captures come out of the writer unchanged."""
    from mmatch.drivers.ti.tlv import AzimuthStaticHeatMap, RangeProfile
    from mmatch.drivers.ti.writer import TI_PC3D_UNITS

    # SDK 3.3: a 768-byte packet with 20 bytes of padding (33 points + side info + stats)
    sdk33 = encode_frame(make_points(33), 1, "sdk3", extra_tlvs=[Stats()])
    assert len(sdk33) == 768 and sdk33[748:] == bytes(20)
    assert decode_ok(sdk33).points.shape == (33, 5)
    # IWR1443 SDK 2.1: 36-byte header, Q9 points, 512-B range profile (256 bins),
    # 8192-B azimuth heat map (256 x 8 virtual antennas x 4 B)
    rp = RangeProfile(np.arange(256, dtype="<u2"))
    hm = AzimuthStaticHeatMap(np.zeros(256 * 8, dtype=[("imag", "<i2"), ("real", "<i2")]))
    iwr = encode_frame(make_points(5, max_range=20.0), 2, "xwr14xx", extra_tlvs=[rp, hm])
    pkt = decode_ok(iwr)
    assert pkt.header.size == 36 and pkt.tlvs[0].q_format == 9
    assert [len(t.to_bytes()) for t in pkt.tlvs[1:]] == [512, 8192]
    assert pkt.tlvs[2].complex(8).shape == (256, 8)
    # 3D people counting frame 1: 48 + 132 = 180 bytes (13 compressed points, TI's units)
    pc = encode_frame(make_points(13, max_range=10.0), 1, "pc3d", units=TI_PC3D_UNITS)
    assert len(pc) == 180 and struct.unpack_from("<I", pc, 52)[0] == 132
    assert decode_ok(pc).tlvs[0].units == pytest.approx(TI_PC3D_UNITS)
