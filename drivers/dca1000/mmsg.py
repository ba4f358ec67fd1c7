"""Batched UDP I/O with Linux recvmmsg/sendmmsg through ctypes (stdlib only).

One system call moves up to `batch` datagrams; each datagram is scattered into two buffers:
its 10-byte DCA1000 header into row i of `headers` and its payload into `payload[i*P:(i+1)*P]`,
so a run of in-order packets lands as one contiguous stream segment. `available()` is False
where the calls do not exist (non-Linux); callers then fall back to one datagram per call.
"""

from __future__ import annotations

import ctypes
import errno
import os
import socket

import numpy as np

from .protocol import DATA_HEADER_BYTES, MAX_PAYLOAD_BYTES


class _Iovec(ctypes.Structure):
    _fields_ = [("iov_base", ctypes.c_void_p), ("iov_len", ctypes.c_size_t)]


class _Msghdr(ctypes.Structure):
    _fields_ = [
        ("msg_name", ctypes.c_void_p),
        ("msg_namelen", ctypes.c_uint32),
        ("msg_iov", ctypes.POINTER(_Iovec)),
        ("msg_iovlen", ctypes.c_size_t),
        ("msg_control", ctypes.c_void_p),
        ("msg_controllen", ctypes.c_size_t),
        ("msg_flags", ctypes.c_int),
    ]


class _Mmsghdr(ctypes.Structure):
    _fields_ = [("msg_hdr", _Msghdr), ("msg_len", ctypes.c_uint)]


MSG_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0x40)
MSG_TRUNC = getattr(socket, "MSG_TRUNC", 0x20)

try:
    _libc = ctypes.CDLL(None, use_errno=True)
    _recvmmsg = _libc.recvmmsg
    _recvmmsg.argtypes = [
        ctypes.c_int,
        ctypes.POINTER(_Mmsghdr),
        ctypes.c_uint,
        ctypes.c_int,
        ctypes.c_void_p,
    ]
    _recvmmsg.restype = ctypes.c_int
    _sendmmsg = _libc.sendmmsg
    _sendmmsg.argtypes = [ctypes.c_int, ctypes.POINTER(_Mmsghdr), ctypes.c_uint, ctypes.c_int]
    _sendmmsg.restype = ctypes.c_int
except (OSError, AttributeError):  # pragma: no cover - non-Linux
    _recvmmsg = _sendmmsg = None


def available() -> bool:
    return _recvmmsg is not None and _sendmmsg is not None


class _Batch:
    """`batch` messages of two iovecs each (header row, payload slot)."""

    def __init__(self, batch: int) -> None:
        self.batch = batch
        self.msgs = (_Mmsghdr * batch)()
        self.iov = (_Iovec * (2 * batch))()
        base = ctypes.addressof(self.iov)
        size = ctypes.sizeof(_Iovec)
        for i in range(batch):
            h = self.msgs[i].msg_hdr
            h.msg_iov = ctypes.cast(base + 2 * i * size, ctypes.POINTER(_Iovec))
            h.msg_iovlen = 2
        # numpy views of the iovec fields and of msg_len / msg_flags for vectorised access
        self.iov_u64 = np.frombuffer(self.iov, dtype=np.uint64).reshape(2 * batch, 2)
        raw = np.frombuffer(self.msgs, dtype=np.uint8).reshape(batch, ctypes.sizeof(_Mmsghdr))
        self.msg_len = raw[:, _Mmsghdr.msg_len.offset : _Mmsghdr.msg_len.offset + 4].view("<u4")[
            :, 0
        ]
        off = _Mmsghdr.msg_hdr.offset + _Msghdr.msg_flags.offset
        self.msg_flags = raw[:, off : off + 4].view("<i4")[:, 0]


class BatchReceiver:
    """recvmmsg into fixed buffers: headers (batch, 10) uint8 and payload (batch * P,) uint8."""

    def __init__(
        self, sock: socket.socket, batch: int = 64, payload_bytes: int = MAX_PAYLOAD_BYTES
    ) -> None:
        self.fd = sock.fileno()
        self.P = payload_bytes
        self.b = _Batch(batch)
        self.headers = np.zeros((batch, DATA_HEADER_BYTES), dtype=np.uint8)
        self.payload = np.zeros(batch * payload_bytes, dtype=np.uint8)
        hb = self.headers.ctypes.data
        pb = self.payload.ctypes.data
        iov = self.b.iov_u64
        iov[0::2, 0] = hb + DATA_HEADER_BYTES * np.arange(batch, dtype=np.uint64)
        iov[0::2, 1] = DATA_HEADER_BYTES
        iov[1::2, 0] = pb + payload_bytes * np.arange(batch, dtype=np.uint64)
        iov[1::2, 1] = payload_bytes

    def recv(self) -> int:
        """Receive up to `batch` datagrams without blocking; 0 when none is waiting."""
        n = _recvmmsg(self.fd, self.b.msgs, self.b.batch, MSG_DONTWAIT, None)
        if n < 0:
            e = ctypes.get_errno()
            if e in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
                return 0
            raise OSError(e, os.strerror(e))
        return n

    def fields(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(seq, byte count, datagram length, truncated flag) of the first n datagrams."""
        h = self.headers[:n]
        seq = h[:, 0:4].copy().view("<u4")[:, 0].astype(np.int64)
        lo = h[:, 4:8].copy().view("<u4")[:, 0].astype(np.int64)
        hi = h[:, 8:10].copy().view("<u2")[:, 0].astype(np.int64)
        return (
            seq,
            lo | (hi << 32),
            self.b.msg_len[:n].astype(np.int64),
            (self.b.msg_flags[:n] & MSG_TRUNC) != 0,
        )


class BatchSender:
    """sendmmsg of DCA1000 data packets from a source buffer on a connected UDP socket."""

    def __init__(self, sock: socket.socket, source: bytes, batch: int = 64) -> None:
        self.fd = sock.fileno()
        self.b = _Batch(batch)
        self.headers = np.zeros((batch, DATA_HEADER_BYTES), dtype=np.uint8)
        self._src = np.frombuffer(source, dtype=np.uint8)
        self._src_addr = self._src.ctypes.data
        iov = self.b.iov_u64
        iov[0::2, 0] = self.headers.ctypes.data + DATA_HEADER_BYTES * np.arange(
            batch, dtype=np.uint64
        )
        iov[0::2, 1] = DATA_HEADER_BYTES

    def send(
        self, seq: np.ndarray, byte_count: np.ndarray, src_offset: np.ndarray, length: np.ndarray
    ) -> int:
        """Send len(seq) <= batch packets: header (seq, byte_count) + source[src_offset:+length]."""
        n = len(seq)
        h = self.headers[:n]
        h[:, 0:4] = seq.astype("<u4").view(np.uint8).reshape(n, 4)
        h[:, 4:8] = (byte_count & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(n, 4)
        h[:, 8:10] = (byte_count >> 32).astype("<u2").view(np.uint8).reshape(n, 2)
        iov = self.b.iov_u64
        iov[1 : 2 * n : 2, 0] = self._src_addr + src_offset.astype(np.uint64)
        iov[1 : 2 * n : 2, 1] = length.astype(np.uint64)
        sent = 0
        while sent < n:
            r = _sendmmsg(self.fd, ctypes.byref(self.b.msgs[sent]), n - sent, 0)
            if r < 0:
                e = ctypes.get_errno()
                if e == errno.EINTR:
                    continue
                raise OSError(e, os.strerror(e))
            sent += r
        return sent
