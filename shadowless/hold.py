"""Keeping a rig on this machine up until the operator stops it (`shadowless local --hold`,
`shadowless demo --serve`): say where its console is and how to log in, then wait for Ctrl-C
(SIGINT) or SIGTERM, and return so that the caller's ``with`` blocks stop every process it started
and remove what it made."""
from __future__ import annotations

import asyncio
import signal
import sys
from pathlib import Path
from typing import TextIO

__all__ = ["console_lines", "hold"]


def console_lines(url: str, rig_dir: Path) -> list[str]:
    """What an operator needs to log in to the console of a rig started here."""
    token = Path(rig_dir) / "token"
    return [f"operator console: {url}",
            f"log in with the rig token: paste the contents of {token} (e.g. `cat {token}`); "
            f"a token login is an admin",
            f"name operators with `shadowless rig user add NAME --role operator --rig-dir {rig_dir}`"]


async def hold(lines: list[str], *, then: str = "every process stops", stream: TextIO | None = None) -> str:
    """Print ``lines`` and a last one saying how to stop and what happens ``then``, then wait for
    SIGINT or SIGTERM; returns the signal's name. The signals are this coroutine's only while it waits: the handlers the process had
    before (a second Ctrl-C interrupts the clean-up as usual; SIGTERM still runs
    :mod:`shadowless.exit_cleanup`) are put back afterwards."""
    out = stream or sys.stderr
    loop = asyncio.get_running_loop()
    got = loop.create_future()

    def on(sig: signal.Signals) -> None:
        if not got.done():
            got.set_result(sig.name)

    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in before:
        loop.add_signal_handler(sig, on, sig)
    try:
        for line in lines:
            print(line, file=out, flush=True)
        print(f"the rig stays up until Ctrl-C (or SIGTERM); then {then}", file=out, flush=True)
        name = await got
    finally:
        for sig, handler in before.items():     # the process's own again (its clean-up on SIGTERM among them)
            loop.remove_signal_handler(sig)
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
    print(f"{name}: stopping the rig", file=out, flush=True)
    return name
