"""How `shadowless content` shows assets and progress: tables, JSON, sizes, progress bars
(shared by the local commands, :mod:`rigctl.content_commands`, and the remote ones,
:mod:`rigctl.content_remote`), and :func:`operator_console`, the rich console every
operator table and progress bar is drawn on."""
from __future__ import annotations

import datetime
import json
import shutil
import sys
from typing import TextIO

from rich import box
from rich.console import Console
from rich.progress import (BarColumn, DownloadColumn, Task, TaskProgressColumn, TextColumn, TimeElapsedColumn,
                           TimeRemainingColumn, TransferSpeedColumn)
from rich.progress import Progress as Bars
from rich.table import Table

from protos.asset_manifest import Manifest

#: progress is shown on stderr when the input is at least this large
PROGRESS_MIN_BYTES = 64 << 20
#: the console width tables are drawn at: more than any table needs, so none is squeezed
UNCUT = 10_000


def _isatty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):       # no isatty, or closed
        return False


def operator_console(stream: TextIO, *, tty: bool | None = None, width: int | None = None) -> Console:
    """A rich console on ``stream`` (no markup, no highlighting). On a terminal (``tty``, by
    default ``stream.isatty()``): colours, live bars, the terminal's width. Otherwise: plain text,
    never colour codes, and at least 200 columns. ``width`` overrides either."""
    tty = _isatty(stream) if tty is None else tty
    width = width or (None if tty else max(200, shutil.get_terminal_size().columns))
    return Console(file=stream, force_terminal=tty, width=width, markup=False, highlight=False, emoji=False)


def rendered(table: Table, *, tty: bool = False) -> str:
    """``table`` as text for stdout, at its full width whatever the terminal's (no cell is cut;
    a narrow terminal wraps the lines): coloured for a terminal (``tty``), else plain."""
    console = operator_console(sys.stdout, tty=tty, width=UNCUT)
    with console.capture() as cap:
        console.print(table)
    return "\n".join(line.rstrip() for line in cap.get().splitlines())


def operator_table(*columns: str) -> Table:
    """A borderless table with a rule under its header; ``>name`` columns are right-aligned."""
    t = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False)
    for c in columns:
        t.add_column(c.lstrip(">"), justify="right" if c.startswith(">") else "left", no_wrap=True)
    return t


def clock(seconds: float | None) -> str:
    """``83.4`` -> ``'0:01:23'`` (``'?'`` when unknown), as the bars show times."""
    return "?" if seconds is None else str(datetime.timedelta(seconds=int(seconds)))


def human_bytes(n: int) -> str:
    """``1536`` -> ``'1.5 kB'`` (decimal units)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def asset_dict(asset_id: str, m: Manifest) -> dict:
    """One asset as JSON (what `content list --json` prints per asset)."""
    return {"id": asset_id, "kind": m.kind, "name": m.name, "frames": m.frames, "width": m.width,
            "height": m.height, "channels": m.channels, "bit_depth": m.bit_depth, "fps": m.fps,
            "duration_s": round(m.duration_s, 6), "bytes": m.total_bytes, "blobs": len(m.blobs), "extra": m.extra}


def assets_table(rows: list[tuple[str, Manifest]], *, tty: bool = False) -> str:
    """The `content list` table: id prefix, kind, name, frames, size, channels x depth, fps,
    duration, bytes (coloured for a terminal, ``tty``)."""
    t = operator_table("id", "kind", "name", ">frames", ">size", ">depth", ">fps", ">duration", ">bytes")
    for aid, m in rows:
        depth = f"{m.channels}x{m.bit_depth}{'f' if m.bit_depth == 32 else ''}"
        fps = "-" if m.kind == "still" else f"{m.fps:.3f}".rstrip("0").rstrip(".")
        dur = "-" if m.kind == "still" else f"{m.duration_s:.2f} s"
        t.add_row(aid[:12], m.kind, m.name, str(m.frames), f"{m.width}x{m.height}", depth, fps, dur,
                  human_bytes(m.total_bytes))
    text = rendered(t, tty=tty)
    return text if rows else text + "\n(no assets; add one with `shadowless content add PATH`)"


def added_line(m: Manifest, existed: bool) -> str:
    """What `content add` says about the asset it added (or found already stored)."""
    what = f"{m.kind} {m.name!r}: {m.frames} frame(s), {m.width}x{m.height}, {m.channels} ch, {m.bit_depth}-bit"
    what += f", {m.fps:g} fps" if m.kind != "still" else ""
    state = "already stored" if existed else f"added ({len(m.blobs)} file(s), {human_bytes(m.total_bytes)})"
    return f"{state}: {what}"


class Progress:
    """Byte progress (`hashed`, or another verb; with the transfer speed if ``rate``) on stderr,
    for inputs >= PROGRESS_MIN_BYTES: a rich bar with bytes, percentage, elapsed time and ETA on
    a terminal; elsewhere a plain line every 10 % and at the end."""

    def __init__(self, verb: str = "hashed", *, rate: bool = False, stream: TextIO | None = None) -> None:
        self.verb, self.rate = verb, rate
        self.console = operator_console(stream or sys.stderr)
        self._bars: Bars | None = None
        self._tenth = -1

    def __call__(self, done: int, total: int, *, start: int = 0) -> None:
        """``done`` of ``total`` bytes; ``start``: those already done before this run (a resume)."""
        if total < PROGRESS_MIN_BYTES:
            return
        if self._bars is None:
            speed = (TransferSpeedColumn(),) if self.rate else ()
            self._bars = Bars(TextColumn("{task.description}", markup=False), BarColumn(), DownloadColumn(),
                              TaskProgressColumn(), *speed, TimeElapsedColumn(), TimeRemainingColumn(),
                              console=self.console, disable=not self.console.is_terminal)
            self._bars.add_task(self.verb, total=total, completed=start)
            self._bars.start()
        self._bars.update(self._bars.task_ids[0], completed=done, total=total)
        tenth = 10 * done // total if total else 10
        if not self.console.is_terminal and tenth > self._tenth:
            self._tenth = tenth
            self.console.print(self._line(self._bars.tasks[0]), soft_wrap=True)

    def _line(self, t: Task) -> str:
        done, total = int(t.completed), int(t.total or 0)
        pct = 100.0 * done / total if total else 100.0
        speed = f" at {human_bytes(int(t.speed))}/s" if self.rate and t.speed else ""
        when = f"in {clock(t.elapsed)}" if t.finished else f"{clock(t.elapsed)} elapsed, ETA {clock(t.time_remaining)}"
        return f"{self.verb} {human_bytes(done)} / {human_bytes(total)} ({pct:.0f}%){speed}, {when}"

    def end(self) -> None:
        """Stop the bar (it stays on screen as it was)."""
        if self._bars is not None:
            self._bars.stop()
            self._bars, self._tenth = None, -1


def print_assets(rows: list[tuple[str, Manifest]], *, as_json: bool) -> None:
    """`content list`: the table, or JSON for scripts, on stdout."""
    if as_json:
        json.dump([asset_dict(aid, m) for aid, m in rows], sys.stdout, indent=2)
        print()
    else:
        print(assets_table(rows, tty=_isatty(sys.stdout)))
