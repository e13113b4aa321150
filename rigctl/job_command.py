"""Run a coordinator job from the command line and show its progress.

Commands such as `shadowless calibrate` build their parameters, then call
:func:`run_job_command`: it connects (same options as `shadowless status`),
streams the job's events, draws a progress bar with an ETA per stage on a
terminal (plain lines otherwise), and prints the result. Ctrl-C cancels the
job on the coordinator; what it finished is kept, so running it again resumes.
"""
from __future__ import annotations

import asyncio
import json
import sys
from dataclasses import dataclass
from typing import Callable, TextIO

from rich.progress import (BarColumn, MofNCompleteColumn, TaskID, TaskProgressColumn, TextColumn, TimeElapsedColumn,
                           TimeRemainingColumn)
from rich.progress import Progress as Bars

from rigctl.client import CallRefused, OperatorError
from rigctl.link import Client
from rigctl.content_format import clock, operator_console
from rigctl.rig_target import open_client
from coordinator.jobs.context import Event, Progress
from protos import auth


@dataclass
class _Bar:
    """A stage's bar: its rich task (None once done and printed), item, count and last tenth logged."""

    task: TaskID | None
    item: str
    done: int
    tenth: int = -1


class ProgressView:
    """Draws job events on ``stream`` (stderr by default). On a terminal: a rich bar per stage,
    naming its current item, with done/total, percentage, elapsed time, ETA, value and message;
    a finished bar becomes a line above the others. Elsewhere (a log): a plain line when a stage
    or item starts, at every 10 % and when it is done, with its ETA. Log lines go above the bars."""

    def __init__(self, stream: TextIO | None = None):
        self.console = operator_console(stream or sys.stderr)
        self.tty = self.console.is_terminal
        self._bars: Bars | None = None
        self._stages: dict[str, _Bar] = {}

    def event(self, ev: Event) -> None:
        """Show a :class:`Progress` event or a log line."""
        if isinstance(ev, Progress):
            self.progress(ev)
        else:
            self.log(str(ev))

    def progress(self, p: Progress) -> None:
        """One bar per stage: an item counting again from the start (``done`` not above the
        previous item's) gets a new bar; otherwise the count goes on under the new item's name."""
        if self._bars is None:
            self._bars = Bars(TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(),
                              TaskProgressColumn(), TimeElapsedColumn(), TimeRemainingColumn(),
                              TextColumn("{task.fields[note]}", markup=False), console=self.console,
                              disable=not self.tty, speed_estimate_period=600)
            self._bars.start()
        desc = f"{p.stage} {p.item}".rstrip()
        note = p.message        # the emitter labels its figures there; the bare value is for machines
        total = p.total if p.total > 0 else None
        bar = self._stages.get(p.stage)
        if bar is not None and bar.task is None and p.item == bar.item and total is not None and p.done >= total:
            return                                                    # done already, said again
        if bar is not None and (bar.task is None or (p.item != bar.item and p.done <= bar.done)):
            self._retire(bar)
            bar = None
        if bar is None:
            bar = self._stages[p.stage] = _Bar(self._bars.add_task(desc, total=total, completed=p.done, note=note),
                                               p.item, p.done)
        self._bars.update(bar.task, description=desc, total=total, completed=p.done, note=note)
        bar.item, bar.done = p.item, p.done
        finished = total is not None and p.done >= total
        tenth = 10 * p.done // total if total else 0        # finished: 10
        if not self.tty and tenth > bar.tenth:
            bar.tenth = tenth
            self.console.print(self._line(bar), soft_wrap=True)
        if finished:
            self._retire(bar)

    def _line(self, bar: _Bar) -> str:
        t = next(t for t in self._bars.tasks if t.id == bar.task)
        note = f"  {t.fields['note']}" if t.fields["note"] else ""
        if t.total is None:
            return f"{t.description}: {bar.done}{note}"
        total = int(t.total)
        when = f"in {clock(t.elapsed)}" if t.finished else f"{clock(t.elapsed)} elapsed, ETA {clock(t.time_remaining)}"
        return f"{t.description}: {bar.done}/{total} ({100 * bar.done // total}%), {when}{note}"

    def _retire(self, bar: _Bar) -> None:
        """Take a bar off the screen; on a terminal, it is printed above the others as a line."""
        if bar.task is not None:
            line = self._line(bar)
            self._bars.remove_task(bar.task)
            bar.task = None
            if self.tty:
                self._bars.refresh()
                self.console.print(line, soft_wrap=True)

    def log(self, text: str) -> None:
        """A job's log line, above the bars."""
        self.console.print(text, soft_wrap=True)

    def close(self) -> None:
        """Stop drawing; unfinished bars stay on screen as they were. The view may be used again."""
        if self._bars is not None:
            self._bars.stop()
            self._bars = None
            self._stages.clear()


async def run_job(client: Client, kind: str, params: dict, *, view: ProgressView | None = None) -> dict:
    """Run job ``kind`` on the coordinator behind ``client``, drawing its progress; its result."""
    view = view or ProgressView()
    try:
        return await client.run_job(kind, params, on_event=view.event)
    finally:
        view.close()


def run_job_command(args, kind: str, params: dict, *, report: Callable[[dict], str] | None = None) -> int:
    """The body of a job command: run, print the result (``--json`` or ``report``); the exit code."""

    async def go() -> dict:
        async with await open_client(args) as c:
            return await run_job(c, kind, params)

    try:
        result = asyncio.run(go())
    except CallRefused as exc:          # the job refused or failed on the coordinator
        print(f"shadowless {args.command}: {exc}", file=sys.stderr)
        return 1
    except (OperatorError, auth.TokenError) as exc:
        print(f"shadowless {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"shadowless {args.command}: cancelled; finished parts are kept and a new run resumes", file=sys.stderr)
        return 130
    if getattr(args, "json", False) or report is None:
        print(json.dumps(result, indent=2))
    else:
        print(report(result))
    return 0
