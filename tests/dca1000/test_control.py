"""Control client against the fake DCA1000 on 127.0.0.1: sequence, errors, timeouts, retries."""

from __future__ import annotations

import socket
import time

import pytest

from mmatch.drivers.dca1000.control import Dca1000Control, Dca1000Error
from mmatch.drivers.dca1000.fake import FakeDca1000
from mmatch.drivers.dca1000.protocol import (
    Cmd,
    FpgaConfig,
    FpgaVersion,
    LvdsMode,
    PacketConfig,
    ResponsePacket,
)
from mmatch.errors import DeviceTimeout

FRAME = 4096


def _fake(**kw) -> FakeDca1000:
    return FakeDca1000(bytes(FRAME), FRAME, 2, ("127.0.0.1", 9), **kw)


def _client(fake: FakeDca1000, **kw) -> Dca1000Control:
    kw.setdefault("timeout_s", 0.3)
    return Dca1000Control("127.0.0.1", fake.control_address[1], local=("127.0.0.1", 0), **kw)


def test_setup_sequence_reaches_the_fpga():
    with _fake(version=FpgaVersion(2, 9, False)) as fake, _client(fake) as ctl:
        version = ctl.setup(FpgaConfig(), PacketConfig(1470, 25.0))
        assert version == FpgaVersion(2, 9, False)
        assert [c for c, _ in fake.commands] == [
            Cmd.SYSTEM_CONNECT,
            Cmd.READ_FPGA_VERSION,
            Cmd.CONFIG_FPGA_GEN,
            Cmd.CONFIG_PACKET_DATA,
        ]
        assert fake.fpga_config.lvds_mode is LvdsMode.FOUR_LANE
        assert fake.commands[2][1] == bytes.fromhex("01010102031e")
        assert fake.packet_config == PacketConfig(1470, 25.0)
        assert ctl.retried == 0


def test_error_status_raises_with_command_name():
    with _fake(fail={Cmd.RECORD_START: 5}) as fake, _client(fake) as ctl:
        with pytest.raises(Dca1000Error, match="RECORD_START.*status 5") as info:
            ctl.start_record()
        assert info.value.status == 5


def test_wrong_fpga_payload_is_refused_by_the_fpga():
    # the OpenRadar bug: packet-config bytes sent with the FPGA-config code
    with _fake() as fake, _client(fake) as ctl:
        with pytest.raises(Dca1000Error, match="CONFIG_FPGA_GEN"):
            ctl.command(Cmd.CONFIG_FPGA_GEN, bytes.fromhex("c005350c0000"))


def test_lost_answer_is_retried():
    with _fake(mute=1) as fake, _client(fake, timeout_s=0.2, retries=2) as ctl:
        ctl.connect()
        assert ctl.retried == 1
        assert [c for c, _ in fake.commands] == [Cmd.SYSTEM_CONNECT, Cmd.SYSTEM_CONNECT]


def test_silent_device_times_out():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as dead:
        dead.bind(("127.0.0.1", 0))  # bound but never answers
        with Dca1000Control(
            "127.0.0.1", dead.getsockname()[1], local=("127.0.0.1", 0), timeout_s=0.1, retries=1
        ) as ctl:
            t0 = time.monotonic()
            with pytest.raises(DeviceTimeout, match="SYSTEM_CONNECT.*2 attempts"):
                ctl.connect()
            assert time.monotonic() - t0 < 2.0
            assert ctl.retried == 1


def test_async_report_and_stale_answer_are_skipped():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as dev:
        dev.bind(("127.0.0.1", 0))
        with Dca1000Control(
            "127.0.0.1", dev.getsockname()[1], local=("127.0.0.1", 0), timeout_s=1.0
        ) as ctl:
            host = ("127.0.0.1", ctl._sock.getsockname()[1])
            # before the command: an async "LVDS buffer full" and a stale answer to something else
            dev.sendto(ResponsePacket(Cmd.SYSTEM_ERROR, 9).to_bytes(), host)
            dev.sendto(ResponsePacket(Cmd.RESET_FPGA, 0).to_bytes(), host)
            time.sleep(0.05)
            dev.settimeout(1.0)

            import threading

            def answer():
                buf, addr = dev.recvfrom(64)
                dev.sendto(ResponsePacket(Cmd.SYSTEM_ERROR, 8).to_bytes(), addr)
                dev.sendto(ResponsePacket(Cmd.RECORD_STOP, 0).to_bytes(), addr)

            t = threading.Thread(target=answer)
            t.start()
            ctl.stop_record()
            t.join()
            assert [s for _, s, _ in ctl.async_events] == [9, 8]
            assert ctl.async_events[0][2] == "LVDS buffer full"


def test_close_twice_is_safe():
    with _fake() as fake:
        ctl = _client(fake)
        ctl.close()
        ctl.close()
    fake.close()


def test_async_report_is_polled_without_a_command():
    with _fake() as fake, _client(fake) as ctl:
        ctl.connect()
        fake.report(9)
        deadline = time.monotonic() + 2.0
        events = []
        while not events and time.monotonic() < deadline:
            events = ctl.poll_events()
            time.sleep(0.01)
        assert [(s, t) for _, s, t in events] == [(9, "LVDS buffer full")]
        assert ctl.poll_events() == []
