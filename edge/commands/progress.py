"""A one-line progress display for long command-line runs (stderr, only on a terminal)."""

from __future__ import annotations

import sys
import time


class Progress:
    """Call with (done, total); redraws at most 10 times a second, ends with a newline."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.t0 = time.monotonic()
        self.last = 0.0
        self.tty = sys.stderr.isatty()

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if not self.tty or (now - self.last < 0.1 and done < total):
            return
        self.last = now
        rate = done / max(now - self.t0, 1e-9)
        eta = (total - done) / rate if rate > 0 else 0.0
        sys.stderr.write(f"\r{self.label}: {done}/{total} ({rate:.1f}/s, eta {eta:.0f} s)   ")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()
