"""Run the `shadowless` command in the test's own interpreter, its output captured at the file
descriptors (pytest's ``capfd``), so that a line a C library writes to stderr counts as much as one
Python writes. A corpus of refusals costs a function call per case this way instead of an
interpreter's start; keep a few real processes beside it for what only a process shows (its exit
status as the shell sees it)."""
from __future__ import annotations

import subprocess
import traceback

import pytest

_CAPTURE: dict = {}


def run_shadowless(argv: list[str], capfd) -> tuple[int, str, str]:
    """`shadowless ARGV...` here: (exit status, stdout, stderr). An exception escaping the command
    is printed as a traceback with status 1, as the interpreter would; output pending in ``capfd``
    before the call is dropped."""
    from shadowless.cli import main

    capfd.readouterr()
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    except Exception:   # noqa: BLE001 - the interpreter would print it and exit 1
        traceback.print_exc()
        code = 1
    out, err = capfd.readouterr()
    return code, out, err


@pytest.fixture(autouse=True)
def cli_capture(capfd):
    """Import this into a test module (it is autouse there) whose helpers run commands with
    :func:`run_here` or :func:`shadowless_here`: they read the current test's ``capfd`` through it."""
    _CAPTURE["fd"] = capfd
    yield
    _CAPTURE.clear()


def run_here(argv: list[str]) -> tuple[int, str, str]:
    """:func:`run_shadowless` with the current test's ``capfd`` (needs :func:`cli_capture`)."""
    return run_shadowless(argv, _CAPTURE["fd"])


def shadowless_here(argv: list[str]) -> subprocess.CompletedProcess:
    """:func:`run_here` as a :class:`subprocess.CompletedProcess`, to stand in for a real process's result."""
    code, out, err = run_here(argv)
    return subprocess.CompletedProcess(argv, code, out, err)
