"""The console answers only requests whose Host names it: an address it listens on, localhost on
loopback, or a name of the --console-host allow-list. A DNS-rebinding page (its own name in both
Host and Origin) is refused. Rules first, then a real console and a real HTTP client forging
Host and Origin."""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import socket
from pathlib import Path

import aiohttp
import pytest

from coordinator.console import auth
from coordinator.console.audit import FILE_NAME
from coordinator.console.hosts import HostCheck, allowed_host, is_local_address, split_host
from coordinator.console.service import Console
from coordinator.errors import CoordinatorError
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.app import CoordinatorApp
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"h" * 32


def test_split_host_reads_what_browsers_send():
    assert split_host("127.0.0.1:7680") == ("127.0.0.1", 7680)
    assert split_host("Console.Venue.LAN.:80") == ("console.venue.lan", 80)
    assert split_host("localhost") == ("localhost", None)
    assert split_host("[::1]:7680") == ("::1", 7680)
    assert split_host("[0:0::1]") == ("::1", None)
    for bad in ("", " ", "evil example", "a:b", "127.0.0.1:0", "127.0.0.1:65536", "127.0.0.1:80:80", "[::1",
                "[::1]x", "[127.0.0.1]:80", "-evil.lan", "a..b", "x" * 64 + ".lan", "é.lan", "1234", "127.1",
                "host:+80", "host: 80", "::1", "fd00::1:80", "[fe80::1%eth0]:80", "[fe80::1%25eth0]"):
        with pytest.raises(ValueError, match="is not a host name or IP address|is not a number 1..65535"):
            split_host(bad)


def test_a_console_on_one_address_answers_to_it_and_to_localhost_only_on_its_port():
    check = HostCheck([("127.0.0.1", 7680)])
    for ok in ("127.0.0.1:7680", "localhost:7680", "LOCALHOST:7680", "localhost.:7680"):
        assert check.ok(ok), ok
    for bad in (None, "", "127.0.0.1", "127.0.0.1:7681", "127.0.0.2:7680", "evil.example:7680", "[::1]:7680",
                "localhost.evil.example:7680", "0.0.0.0:7680"):
        assert not check.ok(bad), bad


def test_a_wildcard_console_answers_to_every_address_of_this_machine():
    local = {"10.0.0.2", "192.168.1.7", "127.0.0.1"}
    check = HostCheck([("0.0.0.0", 7680)], is_local=local.__contains__)
    for ok in ("10.0.0.2:7680", "192.168.1.7:7680", "127.0.0.1:7680", "localhost:7680"):
        assert check.ok(ok), ok
    for bad in ("10.0.0.3:7680", "0.0.0.0:7680", "[::1]:7680", "10.0.0.2:80", "console.venue.lan:7680"):
        assert not check.ok(bad), bad
    v6 = HostCheck([("::", 7680)], is_local={"fd00::2", "::1"}.__contains__)
    assert v6.ok("[fd00::2]:7680") and v6.ok("[::1]:7680") and v6.ok("localhost:7680")
    assert not v6.ok("[fd00::3]:7680") and not v6.ok("10.0.0.2:7680"), "asyncio binds :: to IPv6 only"


def test_names_the_operator_allowed_and_the_default_port_of_the_scheme():
    check = HostCheck([("10.0.0.2", 443)], scheme="https", names=["rig.lan"],
                      allowed=["console.venue.lan", "proxy.lan:8443", "[fd00::9]"])
    for ok in ("10.0.0.2", "10.0.0.2:443", "rig.lan", "console.venue.lan", "Console.Venue.Lan:443", "proxy.lan:8443",
               "[fd00::9]:443"):
        assert check.ok(ok), ok
    for bad in ("proxy.lan", "proxy.lan:443", "console.venue.lan:8443", "localhost", "venue.lan", "10.0.0.2:80"):
        assert not check.ok(bad), bad
    with pytest.raises(ValueError):
        HostCheck([("127.0.0.1", 1)], allowed=["not a name"])
    odd = HostCheck([("10.0.0.2", 80)], names=["my_rig", "rig.lan"])     # a listen name no browser can send
    assert odd.ok("rig.lan") and odd.ok("10.0.0.2") and not odd.ok("my_rig")


def test_an_address_is_this_machines_when_a_socket_binds_to_it():
    assert is_local_address("127.0.0.1")
    # TEST-NET-1 (RFC 5737) is nobody's; binding sends nothing anywhere
    assert not is_local_address("192.0.2.1")
    assert not is_local_address("0.0.0.0") and not is_local_address("224.0.0.251")
    assert not is_local_address("255.255.255.255")


def test_the_allow_list_option_refuses_what_is_not_a_name():
    assert allowed_host(" console.venue.lan ") == "console.venue.lan"
    assert allowed_host("[fd00::1]:8443") == "[fd00::1]:8443"
    for bad in ("console venue", "evil.lan:0", "http://evil.lan", "a_b.lan", "https://"):
        with pytest.raises(argparse.ArgumentTypeError) as exc:
            allowed_host(bad)
        assert "\n" not in str(exc.value) and "e.g. console.venue.lan" in str(exc.value)


@contextlib.asynccontextmanager
async def console(tmp_path: Path, hosts: list[str] | None = None):
    rig = Rig(init_rig(tmp_path / "rig", name="hosts", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32))
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0", console_hosts=hosts) as app:
        yield app.coordinator, app.console_port


def client() -> aiohttp.ClientSession:
    return aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar())


def raw_request(port: int, request: bytes) -> tuple[int, dict]:
    """Send ``request`` as is on a plain socket: (status, JSON body)."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(request)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b" ")[1]), json.loads(body)


def test_requests_naming_another_host_are_refused_with_one_line(tmp_path, caplog):
    caplog.set_level(logging.WARNING, logger="coordinator.console.app")

    async def go():
        async with console(tmp_path) as (coord, port), client() as s:
            base = f"http://127.0.0.1:{port}"
            for host in (f"evil.example:{port}", "evil.example", f"127.0.0.1:{port + 1}", f"127.0.0.2:{port}",
                         f"[::1]:{port}", f"localhost.evil.example:{port}", f"127.0.0.1:{port}@evil.example"):
                for path in ("/", "/static/console.js", "/api/status"):
                    r = await s.get(base + path, headers={"Host": host})
                    error = (await r.json())["error"]
                    assert r.status == 421, (host, path, r.status)
                    assert error.startswith(f"refused: Host {host!r} is not an address of this console"), error
                    assert f"open http://127.0.0.1:{port}/" in error and "--console-host" in error
                    assert "\n" not in error
                    assert "frame-ancestors 'none'" in r.headers["Content-Security-Policy"]
            # the rebinding page: its own name in Host and in Origin, which agree; the right token even
            evil = f"evil.example:{port}"
            r = await s.post(base + "/login", json={"token": TOKEN.decode()},
                             headers={"Host": evil, "Origin": f"http://{evil}"})
            assert r.status == 421 and auth.COOKIE not in r.cookies
            assert not (coord.rig.path / FILE_NAME).exists(), "a refused request never reaches the login"
            # a request with no Host header at all (HTTP/1.0)
            status, body = await asyncio.to_thread(raw_request, port, b"GET / HTTP/1.0\r\n\r\n")
            assert status == 421, body
            assert body["error"] == f"refused: the request has no Host header; open {base}/ in a browser", body
            # the log names each refused Host once, however often a page retries it
            refused = [r.getMessage() for r in caplog.records if "is not an address of this console" in r.getMessage()]
            assert sum(f"Host 'evil.example:{port}'" in m for m in refused) == 1, refused
            assert all(m.endswith("(from 127.0.0.1)") for m in refused), refused
            assert "--console-host evil.example" in refused[0]

    asyncio.run(go())


def test_its_own_addresses_and_allowed_names_work_with_their_own_origin(tmp_path):
    async def go():
        async with console(tmp_path, hosts=["console.venue.lan", "proxy.lan:8443"]) as (coord, port), client() as s:
            base = f"http://127.0.0.1:{port}"
            for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"console.venue.lan:{port}", "proxy.lan:8443"):
                r = await s.get(base + "/", headers={"Host": host})
                assert r.status == 200, (host, await r.text())
                r = await s.post(base + "/login", json={"token": TOKEN.decode()},
                                 headers={"Host": host, "Origin": f"http://{host}"})
                assert r.status == 200, (host, await r.text())
                cookie = r.cookies[auth.COOKIE].value
                headers = {"Host": host, "Origin": f"http://{host}", "Cookie": f"{auth.COOKIE}={cookie}",
                           auth.CSRF_HEADER: (await r.json())["csrf"]}
                r = await s.post(base + "/api/blackout", headers=headers)
                assert r.status == 200, (host, await r.text())
                # an allowed Host with the Origin of another allowed name: still not this page's origin
                other = "console.venue.lan" if host.startswith("127.") else "127.0.0.1"
                r = await s.post(base + "/api/stop", headers={**headers, "Origin": f"http://{other}:{port}"})
                assert r.status == 403, host
            for host in ("proxy.lan", f"proxy.lan:{port}", "console.venue.lan:8443"):
                assert (await s.get(base + "/", headers={"Host": host})).status == 421, host

    asyncio.run(go())


def test_a_malformed_allowed_name_stops_the_console_with_one_line(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="hosts", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32))
    coord = CoordinatorApp(rig, TOKEN, listen="127.0.0.1:0", advertise=False).coordinator
    with pytest.raises(CoordinatorError, match=r"^console host 'bad name' is not a host name or IP address; give a"):
        Console(coord, "127.0.0.1:0", hosts=["bad name"])


def _generated_hosts(n: int, seed: int = 35) -> list[str]:
    """Host header values of every shape, valid and not: names, IPv4, IPv6 (bracketed or not),
    with and without ports, mangled by a random character now and then."""
    import random

    rnd = random.Random(seed)
    alphabet = "abcxyz019-._:[]% é\t@/"
    out = []
    for _ in range(n):
        kind = rnd.randrange(5)
        if kind == 0:
            host = ".".join("".join(rnd.choice("abz09-") for _ in range(rnd.randint(1, 8))) for _ in range(rnd.randint(1, 4)))
        elif kind == 1:
            host = ".".join(str(rnd.randint(0, 300)) for _ in range(4))
        elif kind == 2:
            host = "[" + ":".join(f"{rnd.randint(0, 0xffff):x}" for _ in range(8)) + "]"
        elif kind == 3:
            host = "[::" + f"{rnd.randint(0, 0xffff):x}" + "]"
        else:
            host = "".join(rnd.choice(alphabet) for _ in range(rnd.randint(1, 12)))
        if rnd.random() < 0.6:
            host += ":" + str(rnd.choice([rnd.randint(1, 65535), 0, 70000, "x", ""]))
        if rnd.random() < 0.1:
            i = rnd.randrange(len(host) + 1)
            host = host[:i] + rnd.choice(alphabet) + host[i:]
        out.append(host)
    return out


def test_split_host_agrees_with_urllib_and_inet_pton_on_what_it_accepts():
    """An independent reference: whatever split_host accepts, urllib's URL parser reads as the
    same host and port, and an IP it accepts is one inet_pton accepts; every well-formed name,
    IPv4 and bracketed IPv6 among the generated values is accepted."""
    from urllib.parse import urlsplit

    accepted = 0
    for value in _generated_hosts(5000):
        try:
            host, port = split_host(value)
        except ValueError:
            continue
        accepted += 1
        ref = urlsplit("http://" + value)
        assert (ref.hostname or "").rstrip(".") == host or ipaddress_equal(ref.hostname, host), (value, host, ref)
        assert ref.port == port, (value, port, ref.port)
        if ":" in host:
            socket.inet_pton(socket.AF_INET6, host)
        elif host.replace(".", "").isdigit():
            socket.inet_pton(socket.AF_INET, host)
    assert accepted > 1000, accepted
    for value in ("a-b.c0", "10.0.0.255:65535", "[fe80::1:2]:1", "[::ffff]"):
        split_host(value)


def ipaddress_equal(a: str | None, b: str) -> bool:
    import ipaddress

    try:
        return ipaddress.ip_address(a) == ipaddress.ip_address(b)
    except ValueError:
        return False
