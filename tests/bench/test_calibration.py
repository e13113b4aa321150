"""`shadowless bench calibration`'s command line: the bust is a surface of its own, and mistakes are
one-line errors before any room is built (the benchmark itself is too long for the suite; the
multiplexed 3D mode it measures is tested in tests/imaging/calibration/test_multiplex3d.py)."""
from __future__ import annotations

import argparse

import pytest

from bench import calibration


def parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="shadowless bench calibration")
    calibration.configure(p)
    return p.parse_args(list(argv))


def test_the_bust_is_a_surface_and_the_help_shows_how(capsys):
    args = parse("--surface", "bust", "--projectors", "1,25")
    assert (args.surface, args.projectors, args.modes) == ("bust", [1, 25], ["sequential", "multiplexed"])
    assert parse().surface == "table"
    with pytest.raises(SystemExit):
        parse("--help")
    assert "--surface bust --projectors 1,25" in capsys.readouterr().out


def test_mistakes_are_one_line_errors(capsys):
    with pytest.raises(SystemExit) as exc:
        parse("--surface", "plaster")
    assert exc.value.code == 2 and "invalid choice: 'plaster'" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="unknown mode 'gray': sequential or multiplexed"):
        calibration.run(parse("--surface", "bust", "--modes", "gray"))
