"""Render one view of a scenario in a process of its own, as a sensor would.

`python -m mmatch.sim.renderd SEED MODE COVISIBLE VIEW` reads requests from stdin and writes
answers to stdout, each a 4-byte little-endian length and a pickle: a request is a scenario
time t (float, s) or None (stop); the answer is the `Observation` of VIEW at t, or the text of
the exception that rendering raised.

Why a process: rendering a frame is Python-heavy (5-20 ms), and a simulated sensor thread in
the vehicle's own process holds the interpreter lock against the frame loop it feeds, which
real sensors (a serial port, a UDP socket) never do. `RenderProcess` is the client the live
simulated sensors use; it raises RenderError when the child is gone or late, and the sensor
(edge/sources/sim.py) then renders in its own process (counted, logged once).
"""

from __future__ import annotations

import os
import pickle
import select
import struct
import subprocess
import sys
import time
from typing import Any, BinaryIO

_LEN = struct.Struct("<I")


def _send(stream: BinaryIO, obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_LEN.pack(len(data)) + data)
    stream.flush()


def _read_exact(stream: BinaryIO, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = stream.read(n - len(out))
        if not chunk:
            raise EOFError("render process closed its pipe")
        out += chunk
    return out


def _recv(stream: BinaryIO) -> Any:
    (n,) = _LEN.unpack(_read_exact(stream, _LEN.size))
    return pickle.loads(_read_exact(stream, n))


class RenderError(RuntimeError):
    """The render process is gone or did not answer in time."""


class RenderProcess:
    """Observations of `view` rendered by a child process (see the module docstring).

    `observe(t, timeout_s)` returns the Observation at scenario time t; raises RenderError
    when the child is gone or slower than timeout_s (the caller then renders itself).
    """

    def __init__(self, seed: int, mode: str, covisible: int, view: str) -> None:
        args = [sys.executable, "-m", "mmatch.sim.renderd", str(seed), mode, str(covisible), view]
        self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      bufsize=0)
        self._closed = False

    def observe(self, t: float, timeout_s: float) -> Any:
        if self._closed or self._proc.poll() is not None:
            raise RenderError(f"render process exited ({self._proc.returncode})")
        try:
            _send(self._proc.stdin, float(t))
            deadline = time.monotonic() + timeout_s
            fd = self._proc.stdout.fileno()
            while not select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]:
                if time.monotonic() >= deadline:
                    self.close()  # a late answer would pair with the next request
                    raise RenderError(f"render process took over {timeout_s:.1f} s")
            answer = _recv(self._proc.stdout)
        except (OSError, EOFError, pickle.UnpicklingError, struct.error) as exc:
            self.close()
            raise RenderError(f"render process failed: {exc}") from exc
        if isinstance(answer, str):
            raise RenderError(f"render process: {answer}")
        return answer

    def close(self) -> None:
        """Stop the child (safe twice)."""
        if self._closed:
            return
        self._closed = True
        try:
            _send(self._proc.stdin, None)
            self._proc.stdin.close()
        except OSError:
            pass
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._proc.stdout.close()


def serve(seed: int, mode: str, covisible: int, view: str, inp: BinaryIO, out: BinaryIO) -> int:
    """The child's loop: answer each requested time until None or end of input."""
    from mmatch.sim.scenario import make_scenario

    scenario = make_scenario(seed, mode, covisible=covisible)
    while True:
        try:
            t = _recv(inp)
        except EOFError:
            return 0
        if t is None:
            return 0
        try:
            obs = scenario.observe(view, float(t))
        except Exception as exc:  # the parent hears it and renders itself
            _send(out, f"{type(exc).__name__}: {exc}")
            continue
        _send(out, obs)


def main(argv: list[str]) -> int:
    seed, mode, covisible, view = argv
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb", buffering=0)
    sys.stdout = sys.stderr  # nothing printed by accident may break the framing
    return serve(int(seed), mode, int(covisible), view, sys.stdin.buffer, out)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
