"""The relay a venue runs inside a namespace: a Unix socket in front of a TCP port (standard library only).

The caller's namespace has no route into a venue (:mod:`shadowless.netns`), but filesystem sockets
belong to no network namespace. So :meth:`~shadowless.netns.Venue.unix_relay` starts this relay
inside a host's namespace: it accepts connections on a Unix socket *path* and forwards each to a
TCP address in that namespace (e.g. the coordinator's gRPC port), and ``unix:PATH`` then reaches
that port from anywhere on the machine.

The relay runs as a file (``python -I shadowless/netns_relay.py --unix PATH --to HOST:PORT``, see
:func:`relay_command`) with the standard library alone, so it needs nothing importable in the
namespace it runs in. It stops on SIGTERM, SIGINT or SIGHUP and removes its socket.
"""
from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sys
from pathlib import Path

__all__ = ["add_arguments", "main", "relay", "relay_command", "serve"]


def relay_command(unix_path: str | Path, host: str, port: int) -> list[str]:
    """The argv that runs this relay from ``unix_path`` to ``host:port`` in an isolated interpreter."""
    return [sys.executable, "-I", os.path.abspath(__file__), "--unix", str(unix_path), "--to", f"{host}:{port}"]


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(1 << 16):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass


async def relay(unix_path: str, host: str, port: int) -> None:
    """Forward every connection on the Unix socket ``unix_path`` to ``host:port`` until a signal ends it."""

    async def handle(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        try:
            ur, uw = await asyncio.open_connection(host, port)
        except OSError:     # not listening (yet): the client sees the connection closed and retries
            w.close()
            return
        tasks = [asyncio.create_task(_pipe(r, uw)), asyncio.create_task(_pipe(ur, w))]
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for t in tasks:
            t.cancel()
        w.close()
        uw.close()

    server = await asyncio.start_unix_server(handle, path=unix_path)
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        asyncio.get_running_loop().add_signal_handler(sig, stop.set)
    async with server:
        await stop.wait()
    Path(unix_path).unlink(missing_ok=True)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--unix", required=True)
    p.add_argument("--to", required=True, metavar="HOST:PORT")


def serve(args: argparse.Namespace) -> int:
    host, _, port = args.to.rpartition(":")
    asyncio.run(relay(args.unix, host, int(port)))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="netns_relay.py", description="Unix socket -> TCP relay, run inside a namespace.")
    add_arguments(p)
    return serve(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
