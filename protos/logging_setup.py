"""The one logging set-up of every shadowless process (coordinator, node, its presenter, the tools).

* ``-v``/``-q`` (repeatable) move the level from the command's default (``--log-level``
  names it outright); see :func:`add_verbosity_args` and :func:`level_from_args`.
* On a terminal or into a file, each line is ``TIME LEVEL NAME LOGGER: message`` (the
  logger is left out when NAME starts with it: ``node r0c0: …``, not ``node r0c0 node: …``).
* Under systemd with the output going to the journal (``$JOURNAL_STREAM`` names our stderr),
  the journal stamps the time itself: a line is ``<P>NAME LOGGER: message`` where ``<P>`` is
  the syslog priority of the level (debug 7, info 6, warning 4, error 3, critical 2), which
  journald reads and strips, so ``journalctl -p warning`` works and no time is written twice.

It lives beside the wire definitions because the node (which does not import the
coordinator) and the coordinator's tools share it.
"""
from __future__ import annotations

import argparse
import logging
import os
import sys

__all__ = ["LEVELS", "add_verbosity_args", "level_from_args", "setup", "journald_stderr", "PRIORITIES"]

LEVELS = ("debug", "info", "warning", "error")

#: logging level -> syslog priority (sd-daemon(3) prefixes)
PRIORITIES = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


def journald_stderr(stream=None) -> bool:
    """True when ``stream`` (default stderr) is the journal's stream: ``$JOURNAL_STREAM`` holds
    the ``device:inode`` of the file descriptor systemd connected (systemd.exec(5))."""
    stream = stream or sys.stderr
    spec = os.environ.get("JOURNAL_STREAM", "")
    try:
        dev, ino = (int(x) for x in spec.split(":"))
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):
        return False
    return (st.st_dev, st.st_ino) == (dev, ino)


class _Origin(logging.Filter):
    """Sets ``record.origin``: the logger's name and a colon, or nothing when the line's tag
    already starts with it (a node's own logger is "node", its tag "node r0c0")."""

    def __init__(self, tag: str):
        super().__init__()
        self.first = tag.split(" ", 1)[0]

    def filter(self, record: logging.LogRecord) -> bool:
        record.origin = "" if record.name == self.first else f" {record.name}"
        return True


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        prio = PRIORITIES.get(record.levelno) or (7 if record.levelno < logging.INFO else 3)
        text = super().format(record)
        # a multi-line message (a traceback) keeps its priority on every line
        return "\n".join(f"<{prio}>{line}" for line in text.splitlines() or [""])


class _CurrentStderr(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is when a record is emitted, not to the
    stream that was stderr at set-up: a command run in-process (a test's capture, a redirect)
    replaces and later closes its stderr, and lines must not go to the closed one."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _value) -> None:
        pass  # StreamHandler.__init__ assigns it; the property always answers sys.stderr


def setup(level: int | str = logging.INFO, *, name: str = "", stream=None, journald: bool | None = None) -> None:
    """Route the root logger to ``stream`` (default: the current stderr, looked up at each line)
    at ``level``, each line tagged with ``name`` (e.g. ``"node r0c0"``). ``journald``: None
    detects it (see the module docstring)."""
    if isinstance(level, str):
        level = getattr(logging, level.upper(), logging.INFO)
    if journald is None:
        journald = journald_stderr(stream)
    handler = logging.StreamHandler(stream) if stream is not None else _CurrentStderr()
    handler.addFilter(_Origin(name))
    line = f"{name}%(origin)s: %(message)s" if name else "%(name)s: %(message)s"
    if journald:
        handler.setFormatter(_JournalFormatter(line))
    else:
        handler.setFormatter(logging.Formatter(f"%(asctime)s %(levelname)-7s {line}"))
    root = logging.getLogger()
    for h in list(root.handlers):
        root.removeHandler(h)
        h.close()
    root.addHandler(handler)
    root.setLevel(level)


def add_verbosity_args(p: argparse.ArgumentParser, default: str = "warning", *, nested: bool = False) -> None:
    """``-v``/``-q`` (repeatable) and ``--log-level``, shared by every command. ``default``: the
    command's level, which the help names. ``nested``: on a sub-action's parser, where they add to
    what was given before the action (no defaults of their own, which argparse would let override
    the command's; the help still names the command's)."""
    unset = {"default": argparse.SUPPRESS} if nested else {}
    g = p.add_argument_group("log output")
    g.add_argument("-v", "--verbose", action="count", **(unset or {"default": 0}),
                   help="more log lines (-v: one level below the command's default, -vv: two)")
    g.add_argument("-q", "--quiet", action="count", **(unset or {"default": 0}),
                   help="fewer log lines (-q: one level up, -qq: two)")
    g.add_argument("--log-level", choices=LEVELS, type=str.lower, **(unset or {"default": None}),
                   help=f"the log level outright (default {default}; overrides -v/-q)")
    if not nested:
        p.set_defaults(_log_default=default)


def level_from_args(args: argparse.Namespace) -> int:
    """The logging level the verbosity options of :func:`add_verbosity_args` ask for."""
    if getattr(args, "log_level", None):
        return getattr(logging, args.log_level.upper())
    base = getattr(logging, str(getattr(args, "_log_default", "warning")).upper())
    level = base - 10 * getattr(args, "verbose", 0) + 10 * getattr(args, "quiet", 0)
    return max(logging.DEBUG, min(logging.CRITICAL, level))
