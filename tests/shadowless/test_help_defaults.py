"""Every `shadowless ... --help` page says the default of each option that has one: an operator who
reads `--fade S` or `--log-level` must not have to guess what happens without it. The test walks
every command's argparse parser and its sub-commands' (as `shadowless COMMAND --help` builds them)
and fails on an option with a default (not None, False, empty, or a flag's) whose help does not
name it. A sub-command's ``--log-level`` has no default of its own (it adds to the command's), so
its help must name the command's."""
from __future__ import annotations

import argparse
from collections.abc import Iterator

from shadowless.cli import COMMANDS, build_parser



def parsers(p: argparse.ArgumentParser, path: tuple[str, ...], seen: set[int]
            ) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """A parser and its sub-commands' parsers, each once (an alias names the same parser)."""
    if id(p) in seen:
        return
    seen.add(id(p))
    yield path, p
    for action in getattr(p, "subcommand_actions", ()):
        for name, sp in action.choices.items():
            yield from parsers(sp, path + (name,), seen)


def has_default(action: argparse.Action) -> bool:
    """Whether the option does something of its own when not given (a flag's off, None or an empty
    value is "not given")."""
    if action.nargs == 0 or action.help == argparse.SUPPRESS:        # flags, counts, --help, --version
        return False
    d = action.default
    if d is None or d is False or d == argparse.SUPPRESS:
        return False
    return not (isinstance(d, (str, tuple, list, dict, set)) and len(d) == 0)


def silent_defaults() -> list[tuple[str, str, str]]:
    """(the command's words, the option, its default) of every option whose help hides its default."""
    out = []
    for command in COMMANDS:
        for path, p in parsers(build_parser(command).command_parser, (command,), set()):
            for action in p._actions:
                level = action.dest == "log_level"         # a sub-command's: the command's level applies
                if not (has_default(action) or level):
                    continue
                text = (action.help or "").lower()
                if "default" not in text:
                    out.append((" ".join(path), "/".join(action.option_strings) or action.dest,
                                "the command's" if level else repr(action.default)))
    return out


def test_every_help_page_names_its_defaults():
    hidden = silent_defaults()
    assert not hidden, "help that does not say the default: " + "; ".join(
        f"shadowless {w} {o} (default {d})" for w, o, d in hidden)


def test_the_walk_sees_sub_commands_and_their_log_level():
    """The walk reaches the sub-commands (`rig board`, `cue add`) and their options; the ones fixed
    here say their defaults."""
    seen = {}
    for command in ("rig", "cue", "local"):
        for path, p in parsers(build_parser(command).command_parser, (command,), set()):
            seen[" ".join(path)] = {o: a for a in p._actions for o in a.option_strings}
    assert {"rig board", "cue add", "local"} <= set(seen)
    assert "default 0" in seen["cue add"]["--fade"].help
    assert "default 0" in seen["local"]["--clock-offset-ms"].help
    assert "--log-level" in seen["rig board"] and "--paper" in seen["rig board"]
