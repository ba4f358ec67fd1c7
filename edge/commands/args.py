"""Argument types and the help formatter shared by the `mmatch` sub-commands."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """An integer >= 1 (counts, worker processes); argparse shows the message with the usage."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def unit_interval(text: str) -> float:
    """A number in 0-1 (a probability, a share)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in 0-1, got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in 0-1, got {text!r}")
    return value


class DefaultsFormatter(argparse.HelpFormatter):
    """Appends "(default: X)" to an option's help unless its help already names a default or
    the default says nothing (None, False, SUPPRESS)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default == argparse.SUPPRESS or default == []
                or "default" in text or not action.option_strings):
            return text
        return f"{text} (default: %(default)s)".lstrip()
