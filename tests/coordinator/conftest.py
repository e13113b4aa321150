"""Fixtures of the coordinator's tests."""
from __future__ import annotations

import pytest


@pytest.fixture
def shadowless_main(capsys):
    """``run(*argv)``: `shadowless ARGV...` in this process, as (exit status, stdout, stderr), the
    parser's refusals (which exit from argparse) included."""
    from shadowless.cli import main

    def run(*argv: str) -> tuple[int, str, str]:
        try:
            code = main(list(argv))
        except SystemExit as exc:
            code = exc.code
        out, err = capsys.readouterr()
        return code, out, err

    return run
