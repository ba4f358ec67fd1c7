"""--version, defaults in every --help, and progress lines off a terminal."""

from __future__ import annotations

import argparse
import io
import re
import subprocess
import sys

import pytest

from mmatch.edge.cli import build_parser, main
from mmatch.edge.commands.progress import Progress


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    from mmatch import __version__

    assert capsys.readouterr().out.strip() == f"mmatch {__version__}"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("no sub-commands")


def test_every_default_is_shown_in_help():
    subs = _subparsers(build_parser())
    assert {"sim", "eval", "demo", "run", "replay", "config", "router", "export"} <= set(subs)
    for name, p in subs.items():
        # argparse wraps lines after hyphens too: "consensus-" / "rmnet" is one word
        text = re.sub(r"-\s+", "-", " ".join(p.format_help().split()))
        for action in p._actions:
            d = action.default
            if not action.option_strings or d in (None, False, [], argparse.SUPPRESS):
                continue
            forms = {f"{d}", f"{d:g}" if isinstance(d, float) else f"{d}"}
            shown = any(f"default: {v}" in text or f"default {v}" in text for v in forms)
            assert shown, f"mmatch {name} --help does not show the default of {action.dest} ({d!r})"


def test_sim_help_names_its_defaults():
    text = _subparsers(build_parser())["sim"].format_help()
    assert "(default: 200)" in text and "(default: mixed)" in text and "(default: 1)" in text


def test_progress_off_a_terminal_prints_a_line_every_interval():
    out = io.StringIO()
    now = [0.0]
    p = Progress("eval", interval_s=5.0, stream=out, clock=lambda: now[0])
    for k in range(1, 101):
        now[0] = k * 0.25          # 4 items a second, 25 s in all
        p(k, 100)
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert lines[0] == "eval: 20/100 (4.0/s, eta 20 s)"
    assert len(lines) == 5                       # at 5, 10, 15, 20 s and the end
    assert lines[-1] == "eval: 100/100 done in 25.0 s"


def test_sim_progress_reaches_a_pipe(tmp_path):
    r = subprocess.run([sys.executable, "-m", "mmatch.edge.cli", "sim", "--out", str(tmp_path / "s"),
                        "--n", "2", "--mode", "easy"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "sim: 2/2 done in" in r.stderr
