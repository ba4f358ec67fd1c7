"""Configure a TI radar over its CLI UART (115200 8N1) from a validated .cfg.

Each command line is written with a newline; the device echoes it, answers ``Done`` (or
``Error ...``) and prints its prompt (``mmwDemo:/>``). A line succeeds on ``Done`` or on the
prompt after the echo; ``Error`` (or "not recognized") stops with `RadarConfigError`, and no
answer within the timeout stops with `DeviceTimeout`; both name ``file:line`` and the line.
The cfg is parsed and validated (`mmatch.drivers.ti.cfg.parse_cfg`) before the port is touched.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mmatch.drivers.ti.cfg import RadarCfg, load_cfg
from mmatch.errors import DeviceError, DeviceTimeout

log = logging.getLogger(__name__)

PROMPT = "mmwDemo:/>"
CLI_BAUD = 115200
_ERROR_RE = re.compile(r"(^|\s)(Error\b.*|.*not recognized.*)$", re.MULTILINE)
_DONE_RE = re.compile(r"^\s*Done\s*$", re.MULTILINE)


class RadarConfigError(DeviceError):
    """The radar refused a configuration line (the message names file:line and the answer)."""


@dataclass(frozen=True)
class CommandReply:
    """lineno: line in the cfg file; line: the command sent; answer: what the device said."""

    lineno: int
    line: str
    answer: str


def _classify(text: str, line: str, prompt: str) -> tuple[str, str]:
    """("error", msg) | ("done", "") | ("wait", "") for the answer so far."""
    m = _ERROR_RE.search(text)
    if m:
        return "error", m.group(2).strip()
    if _DONE_RE.search(text):
        return "done", ""
    echo = text.find(line)
    if echo >= 0 and text.find(prompt, echo + len(line)) >= 0:
        return "done", ""
    return "wait", ""


def send_cfg(port: Any, cfg: RadarCfg | str | Path, *, timeout_s: float = 2.0, start_timeout_s: float = 6.0,
             prompt: str = PROMPT, baudrate: int = CLI_BAUD, prompt_grace_s: float = 0.2,
             on_reply: Callable[[CommandReply], None] | None = None) -> list[CommandReply]:
    """Send every command of `cfg` over the CLI port, line by line; return the replies.

    port: an open pyserial-like object (write, read, in_waiting, reset_input_buffer) or a
    port name/URL opened here at `baudrate` and closed afterwards. cfg: a parsed cfg or a
    .cfg path (parsed and validated here, before the port is opened). timeout_s: seconds to
    wait for each answer (`start_timeout_s` for sensorStart, which calibrates first).
    """
    if not isinstance(cfg, RadarCfg):
        cfg = load_cfg(cfg)
    if isinstance(port, str):
        import serial

        try:
            ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0.05)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open CLI port {port!r} at {baudrate} baud: {exc}") from exc
        try:
            return send_cfg(ser, cfg, timeout_s=timeout_s, start_timeout_s=start_timeout_s,
                            prompt=prompt, prompt_grace_s=prompt_grace_s, on_reply=on_reply)
        finally:
            ser.close()
    replies = []
    for lineno, cmd, args in cfg.commands:
        line = " ".join((cmd, *args))
        limit = start_timeout_s if cmd == "sensorStart" else timeout_s
        answer = _send_line(port, line, limit, prompt, prompt_grace_s, f"{cfg.path}:{lineno}")
        if cmd == "baudRate" and hasattr(port, "baudrate"):
            # xWRL6432 (single UART): the device answers at the old rate, then switches
            port.baudrate = int(float(args[0]))
            log.info("%s:%d: port now at %d baud", cfg.path, lineno, port.baudrate)
        reply = CommandReply(lineno, line, answer)
        log.debug("%s:%d %s -> %r", cfg.path, lineno, line, answer)
        if on_reply is not None:
            on_reply(reply)
        replies.append(reply)
    log.info("%s: %d commands accepted", cfg.path, len(replies))
    return replies


def _send_line(ser: Any, line: str, limit: float, prompt: str, grace: float, where: str) -> str:
    try:
        ser.reset_input_buffer()
        ser.write((line + "\n").encode("ascii"))
        ser.flush()
    except OSError as exc:
        raise DeviceError(f"{where}: cannot write {line!r}: {exc}") from exc
    deadline = time.monotonic() + limit
    text = ""
    while True:
        try:
            chunk = ser.read(max(1, ser.in_waiting))
        except OSError as exc:
            raise DeviceError(f"{where}: reading the answer to {line!r}: {exc}") from exc
        text += chunk.decode("ascii", errors="replace")
        state, msg = _classify(text, line, prompt)
        if state == "error":
            raise RadarConfigError(f"{where}: the radar refused {line!r}: {msg}")
        if state == "done":
            break
        if time.monotonic() > deadline:
            raise DeviceTimeout(f"{where}: no 'Done' or prompt within {limit:g} s after {line!r}"
                                f" (got {text.strip()!r})")
    # let the prompt that follows Done arrive, so it is not taken for the next line's answer
    end = time.monotonic() + grace
    after_echo = max(0, text.find(line) + len(line)) if line in text else 0
    while prompt not in text[after_echo:] and time.monotonic() < end:
        text += ser.read(max(1, ser.in_waiting)).decode("ascii", errors="replace")
    return text.strip()
