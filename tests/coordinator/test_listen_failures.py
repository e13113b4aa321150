"""A coordinator that cannot listen says so in one line of its own and exits; a console that cannot
listen stops it too, unless it was made optional, and then `status` says it loudly."""
from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from shadowless.local import LocalRig
from waits import wait_until


@pytest.fixture
def held_port():
    """A port another process-like holder listens on (127.0.0.1)."""
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen(1)
    yield holder.getsockname()[1]
    holder.close()


@pytest.fixture
def rig(tmp_path):
    r = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False).create()
    yield r
    r.close()


def _coordinator(rig: LocalRig, *args: str) -> subprocess.CompletedProcess:
    """The coordinator with ``args``, without mDNS unless they name its interface."""
    mdns = [] if "--mdns-interface" in args else ["--no-mdns"]
    return subprocess.run([sys.executable, "-m", "shadowless", "coordinator", "--rig", str(rig.rig_dir), *mdns,
                           *args], capture_output=True, text=True, timeout=60)


def _cases(port: int):
    """(what, arguments, words of the one line)"""
    return [
        ("gRPC port taken", ["--listen", f"127.0.0.1:{port}", "--no-console"],
         [f"cannot listen on 127.0.0.1:{port}: port {port} is in use", "--listen"]),
        ("console port taken", ["--listen", "127.0.0.1:0", "--console", f"127.0.0.1:{port}"],
         [f"the operator console cannot listen on 127.0.0.1:{port}: port {port} in use", "--console-optional"]),
        ("--listen on an address this host does not have", ["--listen", "10.255.255.1:7600", "--no-console"],
         ["cannot listen on 10.255.255.1:7600", "not an address of this host"]),
        # refused before anything listens
        ("mDNS on an interface that is no address", ["--listen", "127.0.0.1:0", "--console", "127.0.0.1:0",
                                                     "--mdns-interface", "not-an-ip"],
         ["--mdns-interface 'not-an-ip' is not an IPv4 address"]),
        # refused after the gRPC server started: it is stopped before the loop ends (else gRPC's
        # 'Exception ignored ... Event loop is closed' followed the line)
        ("mDNS on an address this host does not have", ["--listen", "127.0.0.1:0", "--no-console",
                                                        "--mdns-interface", "10.255.255.1"],
         ["cannot advertise", "over mDNS on 10.255.255.1", "is it an address of this machine?"]),
    ]


def test_listen_failures_are_one_line_of_ours_and_a_failed_exit(rig, held_port, corpus_table):
    for what, args, words in _cases(held_port):
        r = _coordinator(rig, *args)
        lines = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
        assert r.returncode == 2, f"{what}: exit {r.returncode}\n{r.stdout}{r.stderr}"
        assert len(lines) == 1 and " ERROR " in lines[0], f"{what}:\n" + "\n".join(lines)
        for w in words:
            assert w in lines[0], f"{what}: {w!r} not in {lines[0]!r}"
        assert "add_port" not in r.stderr and "Traceback" not in r.stderr
        corpus_table("coordinator start", what, lines[0].split(" coordinator: ", 1)[-1], r.returncode)


def test_an_optional_console_that_cannot_listen_is_named_in_status(rig, held_port):
    rig.console = True            # LocalRig's console arguments, then ours: the last --console wins
    rig.coordinator_args = ["--console", f"127.0.0.1:{held_port}", "--console-optional"]
    rig.start_coordinator()
    rig.wait_ready()
    wait_until(lambda: rig.log("coordinator"), lambda log: f"console: NOT SERVED (port {held_port} in use)" in log,
               what="the coordinator's log naming the console it could not serve")
    assert f"console: NOT SERVED (port {held_port} in use)" in rig.run_cli(["status"])


def test_a_refused_start_lets_the_next_start_take_the_rig(rig, held_port):
    """In one process (as an embedding tool or test runs it): a start refused for a taken gRPC port
    releases the rig directory's lock, so a start on another port serves the rig."""
    import asyncio

    from coordinator.errors import CoordinatorError
    from coordinator.rig import Rig
    from coordinator.app import CoordinatorApp
    from inprocess_coordinator import inprocess_coordinator

    async def go():
        app = CoordinatorApp(Rig(rig.rig_dir), rig.token, listen=f"127.0.0.1:{held_port}", advertise=False)
        with pytest.raises(CoordinatorError, match=f"port {held_port} is in use"):
            await app.start()
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token) as app:
            assert app.port and app.coordinator.status().console == "off"

    asyncio.run(go())
