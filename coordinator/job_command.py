"""Run a coordinator job from the command line and show its progress.

Commands such as `shadowless calibrate` build their parameters, then call
:func:`run_job_command`: it connects (same options as `shadowless status`),
streams the job's events, draws a progress bar per stage and item on a
terminal (plain lines otherwise), and prints the result. Ctrl-C cancels the
job on the coordinator; what it finished is kept, so running it again resumes.
"""
from __future__ import annotations

import asyncio
import json
import math
import sys
import time
from typing import Callable, TextIO

import grpc

from coordinator.client import Client, OperatorError
from coordinator.rig_target import open_client
from coordinator.jobs.context import Event, Progress
from protos import auth


class ProgressView:
    """Draws job events: one bar per (stage, item) on a TTY, throttled lines elsewhere."""

    def __init__(self, stream: TextIO = sys.stderr, *, width: int = 28):
        self.stream = stream
        self.tty = stream.isatty()
        self.width = width
        self._key: tuple[str, str] | None = None
        self._last_line = 0.0
        self.started = time.monotonic()

    def _bar(self, done: int, total: int) -> str:
        if total <= 0:
            return ""
        frac = min(1.0, done / total)
        full = int(frac * self.width)
        return "[" + "#" * full + "." * (self.width - full) + f"] {done}/{total}"

    def event(self, ev: Event) -> None:
        """Show a :class:`Progress` event or a log line."""
        if isinstance(ev, Progress):
            self.progress(ev)
        else:
            self.log(str(ev))

    def progress(self, p: Progress) -> None:
        key = (p.stage, p.item)
        value = "" if math.isnan(p.value) or p.value == 0 else f" {p.value:.6g}"
        line = f"{p.stage}{' ' + p.item if p.item else ''} {self._bar(p.done, p.total)}{value} {p.message}".rstrip()
        now = time.monotonic()
        if self.tty:
            if self._key is not None and key != self._key:
                self.stream.write("\n")
            self.stream.write("\r\x1b[2K" + line)
            self.stream.flush()
        elif key != self._key or p.done >= p.total or now - self._last_line > 2.0:
            self.stream.write(line + "\n")
            self.stream.flush()
            self._last_line = now
        self._key = key

    def log(self, text: str) -> None:
        if self.tty and self._key is not None:
            self.stream.write("\n")
            self._key = None
        self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._key is not None:
            self.stream.write("\n")
            self.stream.flush()


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
    except (OperatorError, auth.TokenError) as exc:
        print(f"shadowless {args.command}: {exc}", file=sys.stderr)
        return 2
    except grpc.aio.AioRpcError as exc:
        print(f"shadowless {args.command}: {exc.details() or exc.code().name}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"shadowless {args.command}: cancelled; finished parts are kept and a new run resumes", file=sys.stderr)
        return 130
    if getattr(args, "json", False) or report is None:
        print(json.dumps(result, indent=2))
    else:
        print(report(result))
    return 0
