"""Every `mmatch ...` command in the README, the unit README and docs/ parses as written
(systemd/README.md once gave one that failed: `-v` after the sub-command)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from mmatch.edge.cli import build_parser

REPO = Path(__file__).resolve().parents[2]
PAGES = [REPO / "README.md", REPO / "systemd/README.md", *sorted((REPO / "docs").glob("*.md"))]


def documented_commands() -> list[tuple[str, list[str]]]:
    out = []
    for page in PAGES:
        for block in re.findall(r"```[a-z]*\n(.*?)```", page.read_text(), re.S):
            for line in block.splitlines():
                code = line.split(" #", 1)[0].strip()
                for part in re.split(r"&&|(?<!&)&(?!&)|\|", code):
                    try:
                        words = shlex.split(part)
                    except ValueError:
                        continue
                    if words[:1] == ["sudo"]:
                        words = words[1:]
                    if words and (words[0] == "mmatch" or words[0].endswith("/bin/mmatch")):
                        out.append((f"{page.relative_to(REPO)}: {part.strip()}", words[1:]))
    return out


COMMANDS = documented_commands()


def test_the_pages_hold_commands():
    assert len(COMMANDS) >= 10


@pytest.mark.parametrize("where,argv", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_documented_command_parses(where, argv):
    try:
        build_parser().parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"{where}: does not parse (exit {exc.code})")
