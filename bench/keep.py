"""Keep a benchmark's JSON the way docs/benchmarks/ holds it: ``shadowless bench --keep-json FILE
[--note TEXT] NAME ARGS...`` (or the two options after NAME's own).

The benchmark runs as it would without them and still prints its one JSON document; that
document is also written to FILE inside a wrapper that says where it came from::

    {"name": FILE's stem, "command": "shadowless bench NAME ARGS..." (as typed, without the two
     options), "date": "YYYY-MM-DD", "started": "YYYY-MM-DD HH:MM UTC", "duration_s": ...,
     "load": {"start": [1, 5, 15 min], "end": [...]}, "exit_status": ..., "machine": {...},
     "source": TEXT, "result": the benchmark's document}

Paths of scratch files (under the temporary directory) are cut to their names and paths inside
this checkout made relative to it, in the command and the result alike, so a kept JSON names no
file outside the repository; when a scratch path was cut, ``source`` says so. FILE is checked before the
benchmark starts (an hour's run must not end in a refusal) and written at once when it ends, by
rename, so a failed or interrupted run leaves what FILE held before.

``python -m bench.keep FILE [--note TEXT] -- COMMAND ...`` does the same for a command that is not a
benchmark (``shadowless study proxies --json``, ``shadowless coverage ... --json``): its last JSON
document is kept, or its printed lines when it prints none.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import re
import shlex
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

from bench.machine import load, machine

#: the options this module adds, with how many values each takes
OPTIONS = {"--keep-json": 1, "--note": 1}
REPO = Path(__file__).resolve().parent.parent
CUT_NOTE = "Paths of the run's scratch files are cut to their names."


def add_options(parser: argparse.ArgumentParser, *, after_name: bool = False) -> None:
    """``--keep-json`` and ``--note`` on ``shadowless bench`` (``after_name`` False) or on one
    benchmark's parser: there they default to nothing at all, so that a value given before the
    benchmark's name is not overwritten by the benchmark parser's default."""
    extra = {"default": argparse.SUPPRESS} if after_name else {"default": None}
    parser.add_argument("--keep-json", metavar="FILE", **extra,
                        help="also write the benchmark's JSON to FILE (a directory: DIR/NAME.json) wrapped with the "
                             "command, date, machine and load, as docs/benchmarks/ keeps it")
    parser.add_argument("--note", dest="keep_note", metavar="TEXT", **extra,
                        help="with --keep-json: where the run came from (who, beside what), kept as its 'source'")


def target(value: str, bench: str) -> Path:
    """The file ``--keep-json VALUE`` names for benchmark ``bench``; refuses in one line (SystemExit
    with a message) what could not be written, before anything runs."""
    path = Path(value)
    if path.is_dir():
        path = path / f"{bench}.json"
    if path.suffix != ".json":
        raise SystemExit(f"--keep-json {value}: name a .json file or an existing directory")
    parent = path.parent
    if not parent.is_dir():
        raise SystemExit(f"--keep-json {value}: there is no directory {parent}")
    if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise SystemExit(f"--keep-json {value}: {path} cannot be written here")
    return path


def command_as_typed(argv: list[str] | None = None) -> str | None:
    """``shadowless bench ...`` from the words after the program's name (``sys.argv[1:]`` by
    default), without --keep-json and --note and their values; None when no ``bench`` is there."""
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        start = words.index("bench")
    except ValueError:
        return None
    out: list[str] = []
    rest = iter(words[start:])
    for word in rest:
        name = word.split("=", 1)[0]
        if name in OPTIONS:
            if "=" not in word:
                for _ in range(OPTIONS[name]):
                    next(rest, None)
            continue
        out.append(word)
    return "shadowless " + shlex.join(out)


def _scratch_roots() -> list[str]:
    roots = {os.path.realpath(tempfile.gettempdir()), tempfile.gettempdir(), "/tmp"}
    return sorted((r.rstrip("/") for r in roots if r and r != "/"), key=len, reverse=True)


_STOP = r"[^\s'\"()\[\]{},;]"


def cut_paths(value: Any, *, repo: Path = REPO, scratch: list[str] | None = None) -> tuple[Any, bool]:
    """``value`` (JSON: dicts, lists, strings, numbers) with every path under a scratch directory
    (the temporary directory, /tmp) cut to its last name and every path inside ``repo`` made
    relative to it, in strings and in keys; and whether a scratch path was cut.

    >>> cut_paths({"log": "see /tmp/run-x1/logs/node.log:", "n": 2}, repo=Path("/r"), scratch=["/tmp"])
    ({'log': 'see node.log:', 'n': 2}, True)
    """
    scratch = _scratch_roots() if scratch is None else scratch
    repo_s = str(repo).rstrip("/")
    pats = [re.compile(r"(?<![\w./-])" + re.escape(root) + r"(?:/" + _STOP + r"*|(?!" + _STOP + r"))") for root in scratch]
    repo_pat = re.compile(r"(?<![\w./-])" + re.escape(repo_s) + r"(?=/|$|[\s'\"()\[\]{},;:])/?")
    cut = False

    def name(m: re.Match) -> str:
        text = m.group(0)
        tail = ""
        while text and text[-1] in ".:":     # a sentence's full stop or a log line's colon
            tail, text = text[-1] + tail, text[:-1]
        parts = [p for p in text.split("/") if p]
        return (parts[-1] if parts else "") + tail

    def one(s: str) -> str:
        nonlocal cut
        # the checkout first: a checkout under the temporary directory (a clone in /tmp) is still
        # the checkout, its paths made relative, not scratch paths cut to their names
        relative = repo_pat.sub(lambda m: "" if m.group(0).endswith("/") else ".", s)
        new = relative
        for pat in pats:
            new = pat.sub(name, new)
        cut = cut or new != relative
        return new

    def walk(v: Any) -> Any:
        if isinstance(v, str):
            return one(v)
        if isinstance(v, dict):
            return {one(k) if isinstance(k, str) else k: walk(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [walk(x) for x in v]
        return v

    out = walk(value)
    return out, cut


def last_document(text: str) -> Any:
    """The last JSON document among what was printed (a document starts a line with ``{`` or
    ``[``; the lines between documents are skipped); None when there is none."""
    decoder = json.JSONDecoder()
    found = None
    pos = 0
    while pos < len(text):
        line_end = text.find("\n", pos)
        line_end = len(text) if line_end < 0 else line_end
        start = pos + len(text[pos:line_end]) - len(text[pos:line_end].lstrip())
        if start < line_end and text[start] in "{[":
            try:
                doc, end = decoder.raw_decode(text, start)
            except ValueError:
                pos = line_end + 1
                continue
            found, pos = doc, end
            continue
        pos = line_end + 1
    return found


class _Tee(io.TextIOBase):
    """stdout for the run: what the benchmark prints goes where it went before and into a copy."""

    def __init__(self, stream):
        self._stream = stream
        self.copy = io.StringIO()

    def write(self, text: str) -> int:
        self.copy.write(text)
        return self._stream.write(text)

    def flush(self) -> None:
        self._stream.flush()

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def wrap(name: str, command: str, result: Any, *, note: str | None, started: float, finished: float,
         load_start: list[float], load_end: list[float], exit_status: int) -> dict:
    """The kept document (see the module's docstring), paths cut."""
    (command, result), cut = cut_paths([command, result])
    source = (note or "").strip()
    if cut:
        if source and not source.endswith((".", "!", "?", ")")):
            source += "."
        source = f"{source} {CUT_NOTE}".strip()
    return {
        "name": name,
        "command": command,
        "date": time.strftime("%Y-%m-%d", time.gmtime(started)),
        "started": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(started)),
        "duration_s": round(finished - started, 1),
        "load": {"start": load_start, "end": load_end},
        "exit_status": exit_status,
        "machine": machine(),
        "source": source,
        "result": result,
    }


def write(path: Path, doc: dict) -> None:
    """``doc`` into ``path`` by rename (one space of indent, as the kept files are)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n")
    os.replace(tmp, path)


def run_kept(args: argparse.Namespace, run: Callable[[argparse.Namespace], int | None]) -> int:
    """Run one benchmark (``run(args)``) with its printed JSON kept in ``args.keep_json``."""
    path = target(args.keep_json, args.bench)
    note = getattr(args, "keep_note", None)
    for name in ("keep_json", "keep_note"):       # the benchmark's parameters are those of a run without them
        if hasattr(args, name):
            delattr(args, name)
    command = command_as_typed() or f"shadowless bench {args.bench}"
    load_start, started = load(), time.time()
    tee = _Tee(sys.stdout)
    sys.stdout = tee
    try:
        code = int(run(args) or 0)
    finally:
        sys.stdout = tee._stream
    doc = last_document(tee.copy.getvalue())
    if doc is None:
        print(f"shadowless bench: nothing kept in {path}: {args.bench} printed no JSON document", file=sys.stderr)
        return code or 1
    kept = wrap(path.stem, command, doc, note=note, started=started,
                finished=time.time(), load_start=load_start, load_end=load(), exit_status=code)
    write(path, kept)
    status = "" if code == 0 else f" (the benchmark exited {code})"
    print(f"shadowless bench: kept the JSON in {path}{status}", file=sys.stderr)
    return code


# ------------------------------------------------------------------ any command's output
USAGE_EPILOG = """\
examples:
  python -m bench.keep docs/benchmarks/proxies.json -- shadowless study proxies --json
  python -m bench.keep docs/benchmarks/coverage.json --note "after plan --budget 17" -- \\
      shadowless coverage --rig-dir rigs/planned --planned --json

`shadowless bench` has this built in (shadowless bench --keep-json FILE NAME ...); this form is for
the commands that are not benchmarks but print figures the docs quote. The command runs as a
process of its own (`shadowless` is this interpreter's), its output passes through as it comes,
and its last JSON document is kept as the result; a command that prints none has its printed lines
kept instead, as {"text": [lines]}.
"""


def run_command(path: Path, words: list[str], note: str | None) -> int:
    """Run ``words`` (a command line; ``shadowless`` is this interpreter's) with its stdout kept
    in ``path`` as the result: its last JSON document, else its lines as ``{"text": [...]}``."""
    import subprocess

    argv = [sys.executable, "-m", "shadowless", *words[1:]] if words[0] == "shadowless" else words
    load_start, started = load(), time.time()
    copy = io.StringIO()
    try:
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, bufsize=1)
    except OSError as exc:
        raise SystemExit(f"cannot run {words[0]}: {exc.strerror or exc}") from None
    assert proc.stdout is not None
    for line in proc.stdout:
        sys.stdout.write(line)
        copy.write(line)
    code = proc.wait()
    text = copy.getvalue()
    doc = last_document(text)
    if doc is None:
        lines = [line.rstrip() for line in text.splitlines() if line.strip()]
        if not lines:
            print(f"bench.keep: nothing kept in {path}: {words[0]} printed nothing", file=sys.stderr)
            return code or 1
        doc = {"text": lines}
    write(path, wrap(path.stem, shlex.join(words), doc, note=note, started=started, finished=time.time(),
                     load_start=load_start, load_end=load(), exit_status=code))
    status = "" if code == 0 else f" (the command exited {code})"
    print(f"bench.keep: kept the output in {path}{status}", file=sys.stderr)
    return code


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.keep", formatter_class=argparse.RawDescriptionHelpFormatter,
        usage="python -m bench.keep [-h] FILE [--note TEXT] -- COMMAND ...",
        description="Run a command and keep its printed figures as docs/benchmarks/ keeps a benchmark's JSON "
                    "(the command, date, machine, load at start and end, the note, the result).",
        epilog=USAGE_EPILOG)
    parser.add_argument("file", metavar="FILE", help="the .json file to write (a directory: DIR/COMMAND.json)")
    parser.add_argument("--note", metavar="TEXT", help="where the run came from (who, beside what), kept as 'source'")
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        parser.parse_args(argv)           # --help, or a mistake in the options, first
        parser.error("put the command after -- (python -m bench.keep FILE -- COMMAND ...)")
    cut = argv.index("--")
    args = parser.parse_args(argv[:cut])
    words = argv[cut + 1:]
    if not words:
        parser.error("name the command to run after --")
    stem = words[0] if words[0] != "shadowless" or len(words) < 2 else "_".join(w for w in words[1:3] if not w.startswith("-"))
    try:
        path = target(args.file, stem)
    except SystemExit as exc:
        parser.exit(2, f"{parser.prog}: {exc.code}\n")
    return run_command(path, words, args.note)


if __name__ == "__main__":
    sys.exit(main())
