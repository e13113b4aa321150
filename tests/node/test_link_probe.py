"""node/link.py: a link probes its target with a bare TCP connection before it builds a gRPC channel,
so that a node asking a coordinator that is down (every second while it plays on alone) pays for a
refused connect, not for a channel built, tried and torn down.

Real sockets on loopback: a port nothing listens on, a listener that takes connections, and a
target that is not HOST:PORT (left to gRPC, which fails the call itself).
"""
from __future__ import annotations

import asyncio
import socket

import pytest
from waits import wait_until_async

from node.link import CoordinatorLink, LinkError, probe
from protos import auth


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def hello(target: str) -> None:
    async with CoordinatorLink(target) as link:
        await link.hello(protocol_version=1, client_nonce=auth.new_nonce(), slot="r0c0", timeout=2.0)


def test_a_link_to_a_port_nothing_listens_on_fails_on_entering_as_unavailable():
    target = f"127.0.0.1:{free_port()}"
    with pytest.raises(LinkError, match="cannot connect to 127.0.0.1") as info:
        asyncio.run(hello(target))
    assert info.value.code == "UNAVAILABLE" and not info.value.refused


def test_the_probe_opens_and_closes_one_connection_to_a_listener():
    async def go():
        accepted = []

        async def on_connect(reader, writer):
            accepted.append(await reader.read())        # b"": the probe closed without a byte
            writer.close()

        server = await asyncio.start_server(on_connect, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        async with server:
            await probe(f"127.0.0.1:{port}")
            await wait_until_async(lambda: _len(accepted), lambda n: n == 1, what="the probe's connection taken")
        return accepted

    assert asyncio.run(go()) == [b""]


async def _len(items: list) -> int:
    return len(items)


def test_a_bracketed_ipv6_target_is_probed_too():
    with pytest.raises(LinkError, match=r"cannot connect to \[::1\]") as info:
        asyncio.run(probe(f"[::1]:{free_port()}"))
    assert info.value.code == "UNAVAILABLE"


def test_a_target_that_is_not_host_and_port_goes_to_grpc_untried():
    asyncio.run(probe("unix:/nonexistent/socket"))              # no probe for it
    with pytest.raises(LinkError) as info:
        asyncio.run(hello("unix:/nonexistent/socket"))          # gRPC fails the call itself
    assert info.value.code == "UNAVAILABLE"
