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
    """Print ``lines`` and a last one saying how to stop and what happens ``then``, then wait for SIGINT or SIGTERM; returns the
    signal's name. The signals are this coroutine's only while it waits (the loop's handlers are
    removed afterwards, so a second Ctrl-C during the clean-up interrupts as usual)."""
    out = stream or sys.stderr
    loop = asyncio.get_running_loop()
    got = loop.create_future()

    def on(sig: signal.Signals) -> None:
        if not got.done():
            got.set_result(sig.name)

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, on, sig)
    try:
        for line in lines:
            print(line, file=out, flush=True)
        print(f"the rig stays up until Ctrl-C (or SIGTERM); then {then}", file=out, flush=True)
        name = await got
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
    print(f"{name}: stopping the rig", file=out, flush=True)
    return name
