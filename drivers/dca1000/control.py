"""UDP control client for the DCA1000EVM (config port 4096).

Every command waits for its 8-byte response, checks header, footer, command code and status,
retries on timeout and raises a clear error. Asynchronous SYSTEM_ERROR reports the FPGA sends on
the same port (e.g. "LVDS buffer full") are logged and kept in `async_events`.
"""

from __future__ import annotations

import logging
import select
import socket
import time

from mmatch.errors import DecodeError, DeviceError, DeviceTimeout

from .protocol import (
    CONFIG_PORT,
    Cmd,
    CommandPacket,
    FpgaConfig,
    FpgaVersion,
    PacketConfig,
    ResponsePacket,
)

log = logging.getLogger(__name__)

SYSTEM_ERROR_TEXT = {
    0: "no LVDS data",
    1: "no header",
    2: "EEPROM failure",
    3: "SD card detected",
    4: "SD card removed",
    5: "SD card full",
    6: "mode config failure",
    7: "DDR full",
    8: "record completed",
    9: "LVDS buffer full",
    10: "playback completed",
    11: "playback out of sequence",
}


class Dca1000Error(DeviceError):
    """The DCA1000 answered a command with a non-zero status, or answered nonsense."""

    def __init__(self, cmd: int, status: int | None, reason: str) -> None:
        name = Cmd(cmd).name if cmd in Cmd._value2member_map_ else f"0x{cmd:02X}"
        super().__init__(f"DCA1000 {name}: {reason}")
        self.cmd = cmd
        self.status = status


class Dca1000Control:
    """Client for the DCA1000 command port.

    host/port: the FPGA's address (192.168.33.180:4096 on a real board, 127.0.0.1 for
        the fake).
    local: (ip, port) to bind; the real FPGA answers to the host's port 4096, the fake to
        the sender.
    timeout_s: wait per attempt; retries: extra attempts after a timeout (never after an
        error status).
    Use as a context manager; `close()` is safe twice.
    """

    def __init__(
        self,
        host: str = "192.168.33.180",
        port: int = CONFIG_PORT,
        local: tuple[str, int] = ("192.168.33.30", CONFIG_PORT),
        timeout_s: float = 1.0,
        retries: int = 2,
    ) -> None:
        if timeout_s <= 0 or retries < 0:
            raise ValueError("timeout_s must be > 0 and retries >= 0")
        self.address = (host, port)
        self.timeout_s = timeout_s
        self.retries = retries
        self.async_events: list[tuple[float, int, str]] = []
        self.retried = 0
        self._sock: socket.socket | None = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind(local)
        except OSError as exc:
            self._sock.close()
            self._sock = None
            raise DeviceError(
                f"cannot bind DCA1000 control socket to {local[0]}:{local[1]}: {exc}"
            ) from exc
        self._sock.setblocking(False)

    # -- context manager -------------------------------------------------------------------
    def __enter__(self) -> "Dca1000Control":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    # -- generic command -------------------------------------------------------------------
    def command(self, cmd: int, data: bytes = b"", check_status: bool = True) -> ResponsePacket:
        """Send one command and return its response; raises DeviceTimeout or Dca1000Error."""
        if self._sock is None:
            raise DeviceError("DCA1000 control client is closed")
        packet = CommandPacket(cmd, data).to_bytes()
        self._drain()
        for attempt in range(self.retries + 1):
            if attempt:
                self.retried += 1
                log.warning(
                    "DCA1000 %s: no answer within %.2f s, retry %d/%d",
                    Cmd(cmd).name,
                    self.timeout_s,
                    attempt,
                    self.retries,
                )
            self._sock.sendto(packet, self.address)
            response = self._wait_response(cmd)
            if response is None:
                continue
            if check_status and response.status != 0:
                raise Dca1000Error(cmd, response.status, f"failed with status {response.status}")
            log.debug("DCA1000 %s ok (status %d)", Cmd(cmd).name, response.status)
            return response
        raise DeviceTimeout(
            f"DCA1000 {Cmd(cmd).name}: no answer from {self.address[0]}:{self.address[1]} "
            f"after {self.retries + 1} attempts of {self.timeout_s:.2f} s"
        )

    def _drain(self) -> None:
        """Discard stale datagrams (late answers to earlier attempts), keeping async reports."""
        while True:
            try:
                buf = self._sock.recv(2048)
            except (BlockingIOError, InterruptedError):
                return
            self._note_stray(buf)

    def poll_events(self) -> list[tuple[float, int, str]]:
        """Read pending asynchronous reports (e.g. 'LVDS buffer full') without sending anything.

        Returns the new (host time, status, text) events; all are also kept in `async_events`.
        """
        if self._sock is None:
            raise DeviceError("DCA1000 control client is closed")
        before = len(self.async_events)
        self._drain()
        return self.async_events[before:]

    def _note_stray(self, buf: bytes) -> None:
        try:
            r = ResponsePacket.from_bytes(buf)
        except DecodeError:
            log.warning("DCA1000: ignored %d-byte datagram that is not a response", len(buf))
            return
        if r.cmd == Cmd.SYSTEM_ERROR:
            text = SYSTEM_ERROR_TEXT.get(r.status, f"status {r.status}")
            self.async_events.append((time.time(), r.status, text))
            log.warning("DCA1000 reports: %s", text)
        else:
            log.debug("DCA1000: stale answer to 0x%02X dropped", r.cmd)

    def _wait_response(self, cmd: int) -> ResponsePacket | None:
        deadline = time.monotonic() + self.timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self._sock], [], [], left)
            if not ready:
                return None
            try:
                buf, sender = self._sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                continue
            try:
                r = ResponsePacket.from_bytes(buf)
            except DecodeError as exc:
                raise Dca1000Error(
                    cmd, None, f"malformed response {buf[:16].hex()}: {exc}"
                ) from exc
            if r.cmd == cmd:
                return r
            self._note_stray(buf)

    # -- named commands --------------------------------------------------------------------
    def connect(self) -> None:
        """SYSTEM_CONNECT: check the FPGA is alive."""
        self.command(Cmd.SYSTEM_CONNECT)

    def reset_fpga(self) -> None:
        self.command(Cmd.RESET_FPGA)

    def reset_radar(self) -> None:
        self.command(Cmd.RESET_AR_DEV)

    def configure_fpga(self, config: FpgaConfig | None = None) -> None:
        """CONFIG_FPGA_GEN (defaults: raw, 4-lane AWR2243, capture to Ethernet, 16-bit)."""
        self.command(Cmd.CONFIG_FPGA_GEN, (config or FpgaConfig()).to_bytes())

    def configure_packets(self, config: PacketConfig | None = None) -> None:
        """CONFIG_PACKET_DATA: datagram size and inter-packet delay."""
        self.command(Cmd.CONFIG_PACKET_DATA, (config or PacketConfig()).to_bytes())

    def start_record(self) -> None:
        self.command(Cmd.RECORD_START)

    def stop_record(self) -> None:
        self.command(Cmd.RECORD_STOP)

    def fpga_version(self) -> FpgaVersion:
        """READ_FPGA_VERSION; the response status carries the version bits."""
        return FpgaVersion.from_status(
            self.command(Cmd.READ_FPGA_VERSION, check_status=False).status
        )

    def setup(
        self, fpga: FpgaConfig | None = None, packets: PacketConfig | None = None
    ) -> FpgaVersion:
        """The sequence before a capture: connect, read the version, configure FPGA and packets."""
        self.connect()
        version = self.fpga_version()
        log.info("DCA1000 FPGA version %s", version)
        self.configure_fpga(fpga)
        self.configure_packets(packets)
        return version
