"""A fake DCA1000EVM on 127.0.0.1: answers the control protocol and streams raw data over UDP.

The streamed bytes are a raw capture (synthesised or recorded frames, repeated cyclically up to
`num_frames`), cut into 1456-byte payloads with sequence number and byte count like the FPGA;
the last packet is zero-padded. Loss and reordering can be injected (seeded, reproducible), and
the indices of dropped packets are kept so tests know exactly which frames were hit.
Control faults: `fail` maps a command code to the status to answer; `mute` ignores the first
`mute` commands (to exercise client retries).
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time

import numpy as np

from mmatch.errors import DecodeError

from . import mmsg
from .protocol import (
    MAX_PAYLOAD_BYTES,
    Cmd,
    CommandPacket,
    FpgaConfig,
    FpgaVersion,
    PacketConfig,
    ResponsePacket,
)

log = logging.getLogger(__name__)

_HEAD = struct.Struct("<IIH")


class FakeDca1000:
    """Fake FPGA: control server on (127.0.0.1, control_port) and a data streamer.

    source: raw bytes of whole frames (len % frame_bytes == 0) streamed cyclically.
    frame_bytes: raw frame size; num_frames: frames to stream per recording.
    data_dest: (host, port) of the host's data socket.
    loss / reorder: probability that a packet is dropped / swapped with the next one.
    rate_mb_s: pacing in MB/s (None = as fast as possible, like a zero packet delay).
    Use as a context manager; `close()` stops the threads and closes the sockets (safe twice).
    """

    def __init__(
        self,
        source: bytes,
        frame_bytes: int,
        num_frames: int,
        data_dest: tuple[str, int],
        control_port: int = 0,
        loss: float = 0.0,
        reorder: float = 0.0,
        seed: int = 0,
        rate_mb_s: float | None = None,
        payload_bytes: int = MAX_PAYLOAD_BYTES,
        fail: dict[int, int] | None = None,
        mute: int = 0,
        version: FpgaVersion | None = None,
    ) -> None:
        if len(source) == 0 or len(source) % frame_bytes:
            raise ValueError(
                f"source of {len(source)} bytes is not a whole number of {frame_bytes}-byte frames"
            )
        self.frame_bytes = frame_bytes
        self.num_frames = num_frames
        self.total_bytes = frame_bytes * num_frames
        self.payload_bytes = payload_bytes
        self.num_packets = -(-self.total_bytes // payload_bytes)
        # the source plus one packet of wrap-around, so any packet is one contiguous slice
        self._src = bytes(source) + bytes(source[:payload_bytes]) * (
            -(-payload_bytes // len(source))
        )
        self._src_len = len(source)
        self.data_dest = data_dest
        self.loss = loss
        self.reorder = reorder
        self.seed = seed
        self.rate = None if rate_mb_s is None else rate_mb_s * 1e6
        self.fail = dict(fail or {})
        self.mute = mute
        self.version = version if version is not None else FpgaVersion(2, 8, False)
        self.commands: list[tuple[int, bytes]] = []
        self.fpga_config: FpgaConfig | None = None
        self.packet_config: PacketConfig | None = None
        self.dropped: np.ndarray = np.zeros(0, dtype=np.int64)
        self.sent_packets = 0
        self.client: tuple[str, int] | None = None
        self.stream_seconds = 0.0
        self.stream_done = threading.Event()
        self._ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._ctl.bind(("127.0.0.1", control_port))
        self._ctl.settimeout(0.05)
        self.control_address = self._ctl.getsockname()
        self._data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._data.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
        self._stop = threading.Event()
        self._stream_stop = threading.Event()
        self._stream_thread: threading.Thread | None = None
        self._ctl_thread = threading.Thread(
            target=self._serve, name="fake-dca1000-ctl", daemon=True
        )
        self._ctl_thread.start()

    # -- lifecycle -------------------------------------------------------------------------------
    def __enter__(self) -> "FakeDca1000":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._stream_stop.set()
        if self._stream_thread is not None:
            self._stream_thread.join(timeout=10)
        if self._ctl_thread.is_alive():
            self._ctl_thread.join(timeout=5)
        self._ctl.close()
        self._data.close()

    # -- control ---------------------------------------------------------------------------------
    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                buf, sender = self._ctl.recvfrom(4096)
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            try:
                packet = CommandPacket.from_bytes(buf)
            except DecodeError as exc:
                log.warning("fake DCA1000: bad command %s: %s", buf[:16].hex(), exc)
                continue
            self.commands.append((packet.cmd, packet.data))
            self.client = sender
            if self.mute > 0:
                self.mute -= 1
                continue
            status = self._handle(packet)
            try:
                self._ctl.sendto(ResponsePacket(packet.cmd, status).to_bytes(), sender)
            except OSError:
                return

    def _handle(self, packet: CommandPacket) -> int:
        cmd = packet.cmd
        if cmd in self.fail:
            return self.fail[cmd]
        if cmd == Cmd.READ_FPGA_VERSION:
            return self.version.to_status()
        if cmd == Cmd.CONFIG_FPGA_GEN:
            try:
                self.fpga_config = FpgaConfig.from_bytes(packet.data)
            except DecodeError as exc:
                log.warning("fake DCA1000: %s", exc)
                return 1
            return 0
        if cmd == Cmd.CONFIG_PACKET_DATA:
            try:
                self.packet_config = PacketConfig.from_bytes(packet.data)
            except DecodeError:
                return 1
            return 0
        if cmd == Cmd.RECORD_START:
            if self._stream_thread is not None and self._stream_thread.is_alive():
                return 1
            self.start_stream()
            return 0
        if cmd == Cmd.RECORD_STOP:
            self._stream_stop.set()
            return 0
        if cmd in Cmd._value2member_map_:
            return 0
        return 1

    def report(self, status: int) -> None:
        """Send an async SYSTEM_ERROR report (e.g. 9 = LVDS buffer full) to the last client."""
        if self.client is None:
            raise RuntimeError("no client has talked to the fake DCA1000 yet")
        self._ctl.sendto(ResponsePacket(Cmd.SYSTEM_ERROR, status).to_bytes(), self.client)

    @classmethod
    def from_capture(
        cls, path, frame_bytes: int, data_dest: tuple[str, int], num_frames: int | None = None, **kw
    ) -> "FakeDca1000":
        """Replay a recorded *_Raw_*.bin capture (its trailing packet padding is dropped);
        num_frames defaults to the frames in the file."""
        from pathlib import Path

        data = Path(path).read_bytes()
        extra = len(data) % frame_bytes
        if extra and (extra >= MAX_PAYLOAD_BYTES or any(data[-extra:])):
            raise ValueError(
                f"{path}: {len(data)} bytes is not a whole number of {frame_bytes}-byte frames"
            )
        data = data[: len(data) - extra]
        return cls(data, frame_bytes, num_frames or len(data) // frame_bytes, data_dest, **kw)

    # -- data ------------------------------------------------------------------------------------
    def start_stream(self) -> None:
        """Start streaming one recording (also what RECORD_START does)."""
        self._stream_stop.clear()
        self.stream_done.clear()
        self._stream_thread = threading.Thread(
            target=self.stream, name="fake-dca1000-data", daemon=True
        )
        self._stream_thread.start()

    def packet_order(self) -> np.ndarray:
        """Packet indices in sending order after loss and reordering (seeded); sets `dropped`."""
        rng = np.random.default_rng(self.seed)
        order = np.arange(self.num_packets)
        if self.reorder > 0:
            swap = np.flatnonzero(rng.random(self.num_packets - 1) < self.reorder)
            swap = swap[np.insert(np.diff(swap) > 1, 0, True)] if len(swap) else swap  # no chains
            order[swap], order[swap + 1] = order[swap + 1], order[swap].copy()
        if self.loss > 0:
            drop = rng.random(self.num_packets) < self.loss
            self.dropped = np.sort(order[drop])
            order = order[~drop]
        else:
            self.dropped = np.zeros(0, dtype=np.int64)
        return order

    def affected_frames(self) -> set[int]:
        """Frames that lost at least one byte to injected loss."""
        P, F = self.payload_bytes, self.frame_bytes
        out: set[int] = set()
        for i in self.dropped.tolist():
            a, b = i * P, min((i + 1) * P, self.total_bytes)
            if a < self.total_bytes:
                out.update(range(a // F, (b - 1) // F + 1))
        return out

    def stream(self) -> None:
        """Send the recording to data_dest (blocking); batched with sendmmsg where available."""
        order = self.packet_order()
        sock, dest, P = self._data, self.data_dest, self.payload_bytes
        total, n_src = self.total_bytes, self._src_len
        t0 = time.perf_counter()
        sent = 0
        batch = 64
        try:
            sock.connect(dest)
            sender = mmsg.BatchSender(sock, self._src, batch) if mmsg.available() else None
            for j in range(0, len(order), batch):
                if self._stream_stop.is_set():
                    break
                idx = order[j : j + batch].astype(np.int64)
                bc = idx * P
                full = bc + P <= total
                if sender is not None and full.all():
                    sent += sender.send(idx + 1, bc, bc % n_src, np.full(len(idx), P))
                else:
                    for i in idx.tolist():
                        sent += self._send_one(i)
                if self.rate is not None:
                    ahead = sent * P / self.rate - (time.perf_counter() - t0)
                    if ahead > 0:
                        time.sleep(ahead)
        except OSError as exc:
            log.warning("fake DCA1000: data stream stopped: %s", exc)
        finally:
            self.sent_packets = sent
            self.stream_seconds = time.perf_counter() - t0
            self.stream_done.set()

    def _send_one(self, i: int) -> int:
        """Packet i as one datagram (the short last packet is zero-padded like the FPGA's)."""
        P = self.payload_bytes
        bc = i * P
        off = bc % self._src_len
        n = min(P, self.total_bytes - bc)
        payload = self._src[off : off + n] + bytes(P - n)
        self._data.send(_HEAD.pack(i + 1, bc & 0xFFFFFFFF, bc >> 32) + payload)
        return 1


def serve_in_process(
    source: bytes,
    frame_bytes: int,
    num_frames: int,
    data_dest: tuple[str, int],
    control_port: int,
    ready,
    rate_mb_s: float | None = None,
    timeout_s: float = 30.0,
) -> None:
    """Run a FakeDca1000 until its stream has been sent once (multiprocessing.Process target)."""
    with FakeDca1000(
        source, frame_bytes, num_frames, data_dest, control_port=control_port, rate_mb_s=rate_mb_s
    ) as fake:
        ready.set()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if fake.stream_done.wait(0.05) and any(c == Cmd.RECORD_STOP for c, _ in fake.commands):
                log.info(
                    "fake DCA1000 sent %d packets in %.3f s (%.1f MB/s)",
                    fake.sent_packets,
                    fake.stream_seconds,
                    fake.sent_packets * fake.payload_bytes / max(fake.stream_seconds, 1e-9) / 1e6,
                )
                time.sleep(0.05)  # let the RECORD_STOP answer out
                break
