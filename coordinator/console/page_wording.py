"""Refusals that speak to the page: a job's message written for the command line, reworded for
the console's form.

A job refuses in one line, and where the fix is an option it often names the option's flag
(``--charuco board.json --table-only``) or its parameter name (``table_points``). On the page
there are no flags: each option is a field with a human label (the option's own, from
:func:`coordinator.jobs.options.form_fields`). :func:`for_the_page` rewrites what names an option
of that job into its label:

* ``--flag VALUE`` -> ``"Label" set to VALUE``; a true/false flag ``--flag`` -> ``"Label" ticked``
  and ``--no-flag`` -> ``"Label" unticked``; flags one after another are joined with "and";
* a parameter name with an underscore (``table_points``), unless it is a rig.toml key being
  set (``table_points = [...]``), -> ``"Label"``;

and adds, for a few known refusals, what to do on this page (:data:`PAGE_HINTS`). Flags that
are no option of the job (``--camera`` of a command) and everything else stay as they are.
"""
from __future__ import annotations

import functools
import re
from typing import Any, Iterable, Mapping

from coordinator.jobs.errors import JobError
from coordinator.jobs.options import form_fields
from coordinator.jobs.registry import JOBS, resolve

#: (job kind, a phrase of its refusal) -> what to do on the page, added after the refusal
PAGE_HINTS: dict[tuple[str, str], str] = {
    ("calibrate", "needs known points"):
        "On this page: under the camera view, tick “pick points”, click at least four known points of the "
        "table and type where each lies in mm; or choose “the ChArUco board lying on the table”.",
}

#: a flag and, when one follows, its value: a token that looks like one (a number, a path, a file
#: name, a size such as 4x4, a metavar such as N), not a plain word or a bracket of text
_FLAG = re.compile(r"--(no-)?([a-z][a-z0-9]*(?:-[a-z0-9]+)*)(?:[ =](?!--)(?![(\[])([^\s,;)]*[0-9./:A-Z_][^\s,;)]*))?")
_NAME = re.compile(r"(?<![\w\-\[.])([a-z][a-z0-9]*(?:_[a-z0-9]+)+)(?![\w\-])(?!\s*=)")


@functools.lru_cache(maxsize=None)
def _fields(kind: str) -> tuple[dict[str, Any], ...]:
    if kind not in JOBS:
        return ()
    try:
        return tuple(form_fields(resolve(kind).options))
    except JobError:        # a job whose libraries this install lacks
        return ()


def _by_flag(fields: Iterable[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    return {f["flag"][2:]: f for f in fields if f.get("flag")}


def reword(text: str, fields: Iterable[Mapping[str, Any]]) -> str:
    """``text`` with the flags and parameter names of ``fields`` (entries of
    :func:`~coordinator.jobs.options.form_fields`) replaced by their labels (see the module docstring)."""
    fields = list(fields)
    flags = _by_flag(fields)
    names = {f["name"]: f for f in fields}
    out: list[str] = []
    pos = 0
    last_end = -1
    for m in _FLAG.finditer(text):
        negated, flag, value = m.group(1), m.group(2), m.group(3)
        f = flags.get(flag) or (flags.get("no-" + flag) if negated else None)
        if f is None:
            continue
        gap = text[pos:m.start()]
        if last_end == m.start() - len(gap) and last_end >= 0 and not gap.strip():
            gap = " and "
        out.append(gap)
        label = f"“{f['label']}”"
        if f["kind"] == "bool":
            out.append(f"{label} {'unticked' if negated else 'ticked'}")
            if value is not None:       # a bool flag takes no value: what followed is text
                out.append(text[m.start(3) - 1:m.end(3)])
        else:
            out.append(f"{label} set to {value}" if value is not None else label)
        pos = last_end = m.end()
    out.append(text[pos:])
    text = "".join(out)
    return _NAME.sub(lambda m: f"“{names[m.group(1)]['label']}”" if m.group(1) in names else m.group(1), text)


def helps_for_the_page(fields: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A job's form fields (:func:`~coordinator.jobs.options.form_fields`) with their help texts
    reworded as :func:`reword` does (``--no-table`` -> "Use table" unticked)."""
    return [{**f, "help": reword(f["help"], fields)} for f in fields]


def for_the_page(kind: str | None, text: str | None) -> str | None:
    """A job's refusal or message as the page shows it (None and "" pass through)."""
    if not text or not kind:
        return text
    page = reword(text, _fields(kind))
    for (k, phrase), hint in PAGE_HINTS.items():
        if k == kind and phrase in text and hint not in page:
            page = f"{page} {hint}"
    return page


def job_for_the_page(job: dict[str, Any] | None) -> dict[str, Any] | None:
    """The tracker's job snapshot with its error and message reworded for the page (a copy)."""
    if not job:
        return job
    kind = job.get("kind")
    return {**job, "error": for_the_page(kind, job.get("error")), "message": for_the_page(kind, job.get("message"))}
