"""Every failure the command line used to pass over in silence exits non-zero with a message."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.edge.cli import main


def run_cli(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str]:
    """(exit code, stderr) of one `mmatch` call in this process; argparse exits count too."""
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else 1
    return rc, capsys.readouterr().err


def _cases(tmp_path) -> list[tuple[list[str], str]]:
    empty = tmp_path / "empty"
    empty.mkdir()
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "a.npz").write_bytes(b"not a scene")
    np.savez(bad / "b.npz", format=np.array("mmatch-radar/1"))  # misses 'points'
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    return [
        (["eval", str(empty)], "no *.npz scene files"),
        (["eval", str(bad)], "every scene file (2) was rejected"),
        (["sim", "--out", str(tmp_path / "s"), "--n", "0"], "argument --n: must be >= 1, got 0"),
        (["sim", "--out", str(a_file), "--n", "1"], "exists and is not a folder"),
        (["egomotion", str(empty)], "no *.npz radar frame files"),
        (["egomotion", str(bad)], "every radar frame file (2) was rejected"),
        (["eval", str(bad), "--jobs", "0"], "argument --jobs: must be >= 1, got 0"),
        (["sim", "--out", str(tmp_path / "s"), "--jobs", "0"], "argument --jobs: must be >= 1, got 0"),
        (["demo", "--out", str(tmp_path / "d"), "--jobs", "0"], "argument --jobs: must be >= 1, got 0"),
        (["demo", "--out", str(a_file), "--n", "1"], "exists and is not a folder"),
        (["replay", str(a_file), "--fast"], "neither an MCAP log nor a raw TI UART capture"),
    ]


def test_every_silent_failure_exits_non_zero_with_a_message(tmp_path, capsys):
    for argv, message in _cases(tmp_path):
        rc, err = run_cli(argv, capsys)
        assert rc != 0, argv
        assert message in err, (argv, err)
        assert "Traceback" not in err
        assert f"mmatch {argv[0]}: error: " in err, (argv, err)
    assert not (tmp_path / "s").exists()  # nothing was simulated on the way


def test_a_wrong_option_shows_the_subcommands_usage(capsys):
    required = {"sim": ["--out", "x"], "eval": ["x"], "egomotion": ["x"], "demo": [], "bench": [],
                "parse-uart": ["x"], "dsp": ["--cfg", "x", "--adc", "y"], "radar-info": ["--cfg", "x"],
                "run": ["-c", "x"], "replay": ["x"], "config": ["--list"], "router": [],
                "export": ["--ros2", "x", "y"]}
    for cmd, rest in required.items():
        rc, err = run_cli([cmd, *rest, "--no-such-option"], capsys)
        assert rc == 2
        assert f"usage: mmatch {cmd}" in err, err
        assert "--no-such-option" in err


def test_verbose_works_before_and_after_the_subcommand():
    from mmatch.edge.cli import build_parser

    p = build_parser()
    assert p.parse_args(["-v", "sim", "--out", "x"]).verbose == 1
    assert p.parse_args(["sim", "--out", "x", "-vv"]).verbose == 2
    assert p.parse_args(["sim", "--out", "x"]).verbose == 0
    # the command systemd/README.md gives to try a config by hand
    args = p.parse_args(["run", "--config", "/etc/mmatch/vehicle.toml", "--duration", "5", "-v"])
    assert args.verbose == 1 and args.duration == 5.0
