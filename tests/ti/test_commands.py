"""`mmatch parse-uart`, `radar-info`, `radar-config` and the "uart" bench suite."""

from __future__ import annotations

import json
import os
import tty
from pathlib import Path

import numpy as np
import pytest

from mmatch.drivers.ti import bench
from mmatch.drivers.ti.writer import encode_frame
from mmatch.edge.cli import main

from .helpers import make_points, named_fixtures
from .test_io import FakeRadar

REPO = Path(__file__).resolve().parents[2]
VEHICLE_CFG = REPO / "cfg" / "radar" / "xwr18xx_vehicle_100m.cfg"


def test_parse_uart_json_layout(tmp_path, capsys):
    data, want = named_fixtures()["dropped_byte.bin"]
    junk = b"\x00" * 100
    empty = encode_frame(np.zeros((0, 5), np.float32), 9, "sdk3", empty_tlv1="zero_length")
    cap = tmp_path / "cap.bin"
    cap.write_bytes(junk + empty + data)
    out = tmp_path / "out" / "summary.json"
    assert main(["parse-uart", str(cap), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert list(doc) == ["frames", "frame_numbers", "points_per_frame", "bytes_skipped", "rejected",
                         "tlv_types", "first_point"]
    assert doc["frames"] == 4 and doc["frame_numbers"] == [9] + want["frames"]
    assert doc["points_per_frame"] == [0, 5, 3, 6]
    assert doc["bytes_skipped"] == 100 + want["skipped"]
    assert doc["rejected"] == [{"offset": 100 + len(empty) + _first_len(data),
                                "reason": "magic_inside_packet"}]
    assert doc["tlv_types"] == {"1": 4, "7": 3}
    p0 = make_points(5, seed=5)[0]
    fp = doc["first_point"]
    assert list(fp) == ["x", "y", "z", "doppler", "snr"]
    assert [fp["x"], fp["y"], fp["z"], fp["doppler"]] == [float(v) for v in p0[:4]]
    assert fp["snr"] == pytest.approx(float(p0[4]), abs=0.05)
    text = capsys.readouterr().out
    assert "4 frames accepted" in text and "magic_inside_packet 1" in text


def _first_len(data: bytes) -> int:
    import struct

    return struct.unpack_from("<I", data, 12)[0]


def test_parse_uart_empty_capture(tmp_path):
    cap = tmp_path / "empty.bin"
    cap.write_bytes(b"\x01\x02" * 10)
    out = tmp_path / "s.json"
    assert main(["parse-uart", str(cap), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["frames"] == 0 and doc["first_point"] is None and doc["bytes_skipped"] == 20


def test_parse_uart_qformat_with_cfg(tmp_path):
    from mmatch.drivers.ti.cfg import load_cfg

    chirp = load_cfg(VEHICLE_CFG).chirp
    pts = make_points(4, seed=1)
    cap = tmp_path / "sdk2.bin"
    cap.write_bytes(encode_frame(pts, 3, "sdk2", chirp=chirp))
    out = tmp_path / "s.json"
    assert main(["parse-uart", str(cap), "--cfg", str(VEHICLE_CFG), "--json", str(out)]) == 0
    fp = json.loads(out.read_text())["first_point"]
    assert fp["doppler"] == pytest.approx(float(pts[0, 3]), abs=chirp.doppler_resolution_mps / 2)
    assert fp["snr"] == 0.0


def test_radar_info(tmp_path, capsys):
    out = tmp_path / "chirp.json"
    assert main(["radar-info", "--cfg", str(VEHICLE_CFG), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "max +-30.44 m/s" in text and "max 112.50 m" in text and "WARNING" not in text
    doc = json.loads(out.read_text())
    assert doc["num_tx"] == 2 and doc["tx_order"] == [0, 2] and doc["warnings"] == []
    assert main(["radar-info", "--cfg", str(VEHICLE_CFG), "--min-velocity", "40"]) == 0
    assert "WARNING: max velocity 30.44 m/s is below the 40 m/s" in capsys.readouterr().out


def test_radar_info_bad_cfg_exit_code(tmp_path, capsys):
    bad = tmp_path / "bad.cfg"
    bad.write_text("sensorStop\nprofileCfg 0 77\n")
    assert main(["radar-info", "--cfg", str(bad)]) == 2
    assert f"{bad}:2: profileCfg: expected 14 arguments, got 2" in capsys.readouterr().err


def test_radar_config_over_pty(capsys):
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    dev = FakeRadar(master)
    dev.start()
    try:
        assert main(["radar-config", "--port", os.ttyname(slave), "--cfg", str(VEHICLE_CFG)]) == 0
    finally:
        dev.stop.set()
        dev.join(2)
        os.close(master)
        os.close(slave)
    text = capsys.readouterr().out
    assert "commands accepted" in text and dev.received[-1] == "sensorStart"


def test_radar_config_timeout_exit_code(capsys):
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    dev = FakeRadar(master, {"sensorStop": "silent"})
    dev.start()
    try:
        rc = main(["radar-config", "--port", os.ttyname(slave), "--cfg", str(VEHICLE_CFG),
                   "--timeout", "0.2"])
    finally:
        dev.stop.set()
        dev.join(2)
        os.close(master)
        os.close(slave)
    assert rc == 2
    assert "sensorStop" in capsys.readouterr().err


def test_bench_quick():
    res = bench.run(quick=True)
    assert all(isinstance(v, float | int) for v in res.values())
    assert res["reader_mb_per_s"] > 1.0 and res["reader_frames_per_s"] > 10  # sanity only
    assert 300 <= res["points_per_frame_mean"] <= 1000


def test_simulated_radar_end_to_end(capsys):
    """radar-config to the simulated EVM's CLI port, then the real UART path on its data port."""
    from mmatch.drivers.ti.reader import TlvReader
    from mmatch.drivers.ti.simulator import SimulatedRadar
    from mmatch.drivers.ti.sources import SerialSource

    def points(fn):
        return make_points(3 + fn % 5, seed=fn)

    with SimulatedRadar(points, fmt="sdk3", speed=10.0) as sim:
        rc = main(["radar-config", "--port", sim.cli_port, "--cfg", str(VEHICLE_CFG),
                   "--data-port", sim.data_port, "--check-s", "0.3"])
        assert rc == 0 and sim.streaming and sim.chirp.frame_period_ms == 50.0
        text = capsys.readouterr().out
        assert "commands accepted" in text and " frames in " in text
        with SerialSource(sim.data_port) as src:
            reader = TlvReader(src, on_error="skip")
            frames = [reader.read_frame(timeout=2.0) for _ in range(6)]
        assert all(f is not None for f in frames)
        fns = [f.frame_number for f in frames]
        assert fns == list(range(fns[0], fns[0] + 6))
        for f in frames:
            want = points(f.frame_number)
            np.testing.assert_array_equal(f.points[:, :4], want[:, :4])
            assert f.device["timeCpuCycles"] > 0
    sim.close()  # safe twice


def test_simulated_radar_refuses_like_firmware():
    from mmatch.drivers.ti.config_sender import RadarConfigError, send_cfg
    from mmatch.drivers.ti.simulator import SimulatedRadar

    with SimulatedRadar() as sim:
        import serial

        with serial.Serial(sim.cli_port, 115200, timeout=0.05) as ser:
            from mmatch.drivers.ti.config_sender import _send_line

            assert "Ignored" in _send_line(ser, "sensorStop", 2.0, "mmwDemo:/>", 0.2, "t")
            with pytest.raises(RadarConfigError, match="not recognized"):
                _send_line(ser, "fooCfg 1 2", 2.0, "mmwDemo:/>", 0.2, "t")
            with pytest.raises(RadarConfigError, match="Error -1"):
                _send_line(ser, "channelCfg 15 5", 2.0, "mmwDemo:/>", 0.2, "t")
            # sensorStart without a complete profile: the firmware refuses it
            with pytest.raises(RadarConfigError, match="Error -1"):
                _send_line(ser, "sensorStart", 2.0, "mmwDemo:/>", 0.2, "t")
        assert not sim.streaming
        send_cfg(sim.cli_port, VEHICLE_CFG)
        assert sim.streaming


def test_radar_config_data_port_silent_or_wrong_baud():
    import threading
    import time

    from mmatch.drivers.ti.simulator import SimulatedRadar
    from mmatch.edge.commands.radar_config import check_data_port
    from mmatch.errors import DeviceTimeout

    with SimulatedRadar() as sim:  # never configured: the data port stays silent
        with pytest.raises(DeviceTimeout, match="no bytes at all"):
            check_data_port(sim.data_port, 921600, 0.2)
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    stop = threading.Event()

    os.set_blocking(master, False)

    def garble():  # what a 921600-baud stream looks like read at the wrong rate
        while not stop.is_set():
            try:
                os.write(master, bytes(range(1, 200)))
            except BlockingIOError:
                pass
            time.sleep(0.01)

    t = threading.Thread(target=garble, daemon=True)
    t.start()
    try:
        with pytest.raises(DeviceTimeout, match="wrong baud rate"):
            check_data_port(os.ttyname(slave), 921600, 0.3)
    finally:
        stop.set()
        t.join(2)
        os.close(master)
        os.close(slave)
