"""Progress of long command-line runs, on stderr.

On a terminal: one line redrawn at most 10 times a second. Elsewhere (a pipe, a CI log,
the journal): a plain line every `interval_s` seconds and one at the end, so a log shows
that a long run is alive without filling up with redraws.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Call with (done, total); the last call (done == total) ends the display."""

    def __init__(self, label: str, *, interval_s: float = 5.0, stream: TextIO | None = None,
                 clock=time.monotonic) -> None:  # noqa: ANN001
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.clock = clock
        self.t0 = clock()
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval_s = 0.1 if self.tty else interval_s
        self.last = self.t0

    def __call__(self, done: int, total: int) -> None:
        now = self.clock()
        finished = done >= total
        if now - self.last < self.interval_s and not finished:
            return
        self.last = now
        elapsed = max(now - self.t0, 1e-9)
        rate = done / elapsed
        eta = (total - done) / rate if rate > 0 else 0.0
        text = f"{self.label}: {done}/{total} ({rate:.1f}/s, eta {eta:.0f} s)"
        if self.tty:
            self.stream.write(f"\r{text}   " + ("\n" if finished else ""))
        elif finished:
            self.stream.write(f"{self.label}: {done}/{total} done in {elapsed:.1f} s\n")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
