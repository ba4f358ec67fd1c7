"""Health: the systemd notify protocol without dependencies, and rate/drop counters.

`Notifier` sends READY=1, WATCHDOG=1, STATUS=... and STOPPING=1 as datagrams to the
unix socket named by $NOTIFY_SOCKET (an abstract socket when it starts with '@').
Without $NOTIFY_SOCKET every call is a no-op, so the service runs the same by hand.
`watchdog_interval()` reads $WATCHDOG_USEC (and $WATCHDOG_PID) as systemd sets them.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time

log = logging.getLogger(__name__)


class Notifier:
    """sd_notify(3) over $NOTIFY_SOCKET. Errors are logged once, never raised."""

    def __init__(self, address: str | None = None) -> None:
        address = os.environ.get("NOTIFY_SOCKET") if address is None else address
        self._addr: str | bytes | None = None
        self._sock: socket.socket | None = None
        self._warned = False
        self.sent = 0
        if address:
            self._addr = b"\0" + address[1:].encode() if address.startswith("@") else address
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, message: str) -> bool:
        """Send one state string (e.g. "READY=1\\nSTATUS=up"). True when sent."""
        if self._sock is None:
            return False
        try:
            self._sock.sendto(message.encode(), self._addr)
        except OSError as exc:
            if not self._warned:
                log.warning("sd_notify to %r failed: %s", self._addr, exc)
                self._warned = True
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def close(self) -> None:
        """Close the socket; safe twice."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval(env: dict | None = None) -> float | None:
    """Seconds between WATCHDOG=1 pings systemd expects (half of WatchdogSec), or None."""
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    pid = env.get("WATCHDOG_PID")
    if pid and pid.isdigit() and int(pid) != os.getpid():
        return None
    try:
        return max(int(usec) / 1e6 / 2.0, 0.01)
    except ValueError:
        return None


class RateCounter:
    """Counts events and reports the rate over the last `report` call (events/s)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.total = 0
        self._last_total = 0
        self._last_t = time.monotonic()

    def add(self, n: int = 1) -> None:
        with self._lock:
            self.total += n

    def rate(self) -> float:
        """Events per second since the previous call."""
        with self._lock:
            now = time.monotonic()
            dt = max(now - self._last_t, 1e-9)
            r = (self.total - self._last_total) / dt
            self._last_total, self._last_t = self.total, now
            return r


def format_status(rates: dict[str, float], drops: dict[str, int], extra: str = "") -> str:
    """One line for STATUS=: "radar 20.0/s fused 19.8/s | drops radar_queue=1 malformed=0"."""
    parts = " ".join(f"{k} {v:.1f}/s" for k, v in rates.items())
    d = " ".join(f"{k}={v}" for k, v in sorted(drops.items()))
    text = parts + (f" | drops {d}" if d else " | no drops")
    return text + (f" | {extra}" if extra else "")
