"""A hostile mDNS advertiser, for tests and ``bench discovery --hostile``: it claims a rig's instance
name WITHOUT conflict probing (RFC 6762 §9 skipped on purpose: zeroconf's ``cooperating_responders``),
copies the rig's TXT (name and id), reuses the coordinator's host name for its SRV target, and points
at a *tarpit*: a TCP port of its own that accepts connections and never says a word, the costliest
thing a node can be sent to (its handshake waits for a deadline rather than failing at once). It
re-announces every ``--every`` seconds, so its records keep flushing the real coordinator's from
caches (each carries the cache-flush bit).

    python -m bench.mdns_hostile --interface 127.0.0.1 --name table --rig-id ID [--service _x._tcp.local.]

Prints one JSON line ``{"ready": true, "name": ..., "port": ...}`` once it advertises, then runs until
SIGTERM/SIGINT (it unregisters then, politely: this is a test double, not a weapon).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import signal
import socket

from zeroconf import IPVersion
from zeroconf.asyncio import AsyncServiceInfo, AsyncZeroconf

from protos.version import PROTOCOL_VERSION, SERVICE_TYPE


def server_name(rig_id: str) -> str:
    """The SRV target a coordinator of ``rig_id`` on this host uses (coordinator/mdns.py)."""
    return f"{socket.gethostname().split('.')[0] or 'coordinator'}-{rig_id}.local."


async def _tarpit(interface: str) -> tuple[asyncio.AbstractServer, int]:
    held: list[asyncio.StreamWriter] = []

    async def hold(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        held.append(writer)
        try:
            while await reader.read(65536):
                pass
        finally:
            writer.close()

    server = await asyncio.start_server(hold, interface, 0)
    return server, server.sockets[0].getsockname()[1]


async def advertise(*, interface: str, name: str, rig_id: str, service: str, every: float,
                    stop: asyncio.Event) -> None:
    server, port = await _tarpit(interface)
    azc = AsyncZeroconf(interfaces=[interface], ip_version=IPVersion.V4Only)
    info = AsyncServiceInfo(service, f"{name}.{service}", addresses=[socket.inet_aton(interface)], port=port,
                            properties={"rig": rig_id, "proto": str(PROTOCOL_VERSION), "instance": "hostile",
                                        "name": name},
                            server=server_name(rig_id))
    try:
        await azc.async_register_service(info, allow_name_change=False, cooperating_responders=True)
        print(json.dumps({"ready": True, "name": info.name, "port": port}), flush=True)
        while not stop.is_set():
            try:    # not wait_for: on 3.11 it drops a cancel that meets the set stop event
                async with asyncio.timeout(every):
                    await stop.wait()
            except TimeoutError:
                azc.zeroconf.async_send(azc.zeroconf.generate_service_broadcast(info, None))
    finally:
        await azc.async_unregister_all_services()
        await azc.async_close()
        server.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.mdns_hostile", description=__doc__.split("\n\n")[0])
    p.add_argument("--interface", required=True, metavar="IP", help="IPv4 address to advertise on and listen at")
    p.add_argument("--name", required=True, help="the instance name to claim (the rig's name)")
    p.add_argument("--rig-id", required=True, help="the rig id to put in the TXT record")
    p.add_argument("--service", default=SERVICE_TYPE, help=f"service type (default {SERVICE_TYPE})")
    p.add_argument("--every", type=float, default=1.0, help="seconds between re-announcements (default 1)")
    args = p.parse_args(argv)

    async def go() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        await advertise(interface=args.interface, name=args.name, rig_id=args.rig_id, service=args.service,
                        every=args.every, stop=stop)

    asyncio.run(go())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
