"""Helpers of the deploy tests (loaded by file, not imported as a package): a command line as
the real `shadowless` parser takes it."""
from __future__ import annotations

import shlex


def parse_with_the_cli(argv: list[str]):
    """``argv`` (after ``shadowless``) through the real command line's parser, as `main` does:
    the command and every flag must exist and every value must pass its check (an output spec,
    a size, a port). Returns the parsed arguments."""
    from shadowless.cli import COMMANDS, _command_of, build_parser

    command = _command_of(argv)
    assert command in COMMANDS, f"`shadowless {shlex.join(argv)}`: no command {command!r}"
    parser = build_parser(command)
    try:
        args, extra = parser.parse_known_args(argv)
    except SystemExit as exc:
        raise AssertionError(f"`shadowless {shlex.join(argv)}` is refused by the command line") from exc
    assert not extra, f"`shadowless {shlex.join(argv)}`: unrecognized {extra}"
    return args
