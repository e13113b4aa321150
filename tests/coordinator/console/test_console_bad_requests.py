"""The console's bad-input corpus for its Host check and login limits: every refusal is one line
naming what is wrong and what to do, with no traceback in the coordinator's log. HTTP cases go to
a real console with a real client; the option's cases to real `python -m shadowless coordinator`
processes, refused before anything starts. Each row goes to SHADOWLESS_CORPUS_TABLE."""
from __future__ import annotations

import asyncio
import json
import logging
import socket
import subprocess
import sys

import aiohttp
import pytest

from coordinator.console import auth
from coordinator.rig import Rig, grid_slots, init_rig
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"c" * 32

# (name, Host header or None for none at all, Origin or None, path, expected status, words in the line);
# "{port}" is the console's port
HTTP_CASES = [
    ("foreign Host", "evil.example:{port}", None, "/", 421, "Host 'evil.example:{port}' is not an address"),
    ("foreign Host, upper case", "EVIL.example.:{port}", None, "/", 421, "start the coordinator with "
                                                                         "--console-host evil.example"),
    ("Host on another port", "127.0.0.1:1", None, "/api/status", 421, "open http://127.0.0.1:{port}/"),
    ("Host port out of range", "127.0.0.1:99999", None, "/", 421, "is not an address of this console"),
    ("Host 0.0.0.0", "0.0.0.0:{port}", None, "/", 421, "if that name is this machine's, start the coordinator "
                                                       "with --console-host NAME"),
    ("Host with a user part", "127.0.0.1:{port}@evil.example", None, "/", 421, "is not an address"),
    ("Host an unclosed IPv6 bracket", "[::1:{port}", None, "/", 421, "is not an address"),
    ("Host with a control character", "evil.example\t:{port}", None, "/", 421, "is not an address"),
    ("no Host header (HTTP/1.0)", None, None, "/", 421, "the request has no Host header; open http://127.0.0.1:{port}/"),
    ("DNS rebinding: Host and Origin agree", "evil.example:{port}", "http://evil.example:{port}", "/login", 421,
     "is not an address of this console"),
    ("login from a foreign Origin", "127.0.0.1:{port}", "http://evil.example", "/login", 403,
     "does not come from the console's own page"),
    ("login from the same host, other scheme", "127.0.0.1:{port}", "https://127.0.0.1:{port}", "/login", 403,
     "does not come from the console's own page"),
]

# (name, --console-host value, words in the one line)
OPTION_CASES = [
    ("--console-host with a space", "console venue", "'console venue' is not a host name or IP address"),
    ("--console-host port 0", "console.lan:0", "'console.lan:0': port '0' is not a number 1..65535"),
    ("--console-host as a URL", "http://console.lan/", "'http://console.lan/' is a URL, not a name (give "
                                                        "'console.lan' alone)"),
    ("--console-host with an underscore", "my_console.lan", "e.g. console.venue.lan"),
]


def raw(port: int, request: bytes) -> tuple[int, str]:
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(request)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b" ")[1]), body.decode()


@pytest.fixture
def console_port(tmp_path):
    """A coordinator with its console on 127.0.0.1, in a thread's event loop: yields its console port."""
    import threading

    rig = Rig(init_rig(tmp_path / "rig", name="corpus", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32))
    ready, box = threading.Event(), {}

    def run():
        async def main():
            async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app:
                box["app"], box["loop"], box["stop"] = app, asyncio.get_running_loop(), asyncio.Event()
                ready.set()
                await box["stop"].wait()
        asyncio.run(main())

    t = threading.Thread(target=run, name="corpus-coordinator")
    t.start()
    assert ready.wait(60), "the coordinator did not start"
    yield box["app"].console_port, box["app"]
    box["loop"].call_soon_threadsafe(box["stop"].set)
    t.join(60)


def test_bad_requests_get_one_line(console_port, corpus_table, caplog):
    port, app = console_port
    caplog.set_level(logging.DEBUG)
    for name, host, origin, path, status, words in HTTP_CASES:
        host = host.format(port=port) if host else None
        lines = [f"{'POST' if path == '/login' else 'GET'} {path} HTTP/{'1.1' if host else '1.0'}"]
        if host:
            lines.append(f"Host: {host}")
        if origin:
            lines.append(f"Origin: {origin.format(port=port)}")
        body = b'{"token": "%s"}' % TOKEN if path == "/login" else b""
        lines += [f"Content-Length: {len(body)}", "Connection: close"]
        got, text = raw(port, ("\r\n".join(lines) + "\r\n\r\n").encode() + body)
        corpus_table("console request", name, text, got)
        assert got == status, (name, got, text)
        error = json.loads(text)["error"]
        assert "\n" not in error and words.format(port=port) in error, (name, error)

    async def limits():
        base = f"http://127.0.0.1:{port}"
        async with aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
            rows = []
            for _ in range(auth.FREE_FAILURES + 1):
                r = await s.post(base + "/login", json={"token": "wrong"}, headers={"Origin": base})
                rows.append(("wrong token", r.status, (await r.json())["error"]))
            r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": base})
            rows.append(("the right token while the address waits", r.status, (await r.json())["error"]))
            r = await s.post(base + "/login", json={"token": TOKEN.decode()},
                             headers={"Origin": base, "Cookie": f"{auth.DEVICE_COOKIE}=made.up"})
            rows.append(("a forged device cookie while the address waits", r.status, (await r.json())["error"]))
            return rows

    rows = asyncio.run(limits())
    for name, status, error in rows:
        corpus_table("console login", name, error, status)
        assert "\n" not in error
    assert [s for _, s, _ in rows] == [401] * (auth.FREE_FAILURES + 1) + [429, 429]
    assert rows[0][2].startswith("wrong token: paste the rig's token")
    for _, _, error in rows[-2:]:
        assert error.startswith("too many failed logins from 127.0.0.1: try again in ") and error.endswith(" s")
    assert "Traceback" not in caplog.text
    assert len(HTTP_CASES) + len(rows) >= 10


@pytest.mark.parametrize("name, value, words", OPTION_CASES, ids=[c[0] for c in OPTION_CASES])
def test_a_bad_console_host_option_is_one_line_and_status_2(tmp_path, corpus_table, name, value, words):
    rig = init_rig(tmp_path / "rig", name="corpus", slots=grid_slots(1, 1), width=32, height=32, content_width=32,
                   content_height=32)
    r = subprocess.run([sys.executable, "-m", "shadowless", "coordinator", "--rig", str(rig), "--listen",
                        "127.0.0.1:0", "--no-mdns", "--console", "127.0.0.1:0", "--console-host", value],
                       capture_output=True, text=True, timeout=120)
    err = r.stderr.strip()
    corpus_table("CLI", f"shadowless coordinator --console-host {value!r}", err, r.returncode)
    assert "Traceback" not in err and r.returncode == 2, (r.returncode, err)
    assert len(err.splitlines()) == 1 and words in err, err


# (name, raw bytes with {port}, the reason the log line gives)
MALFORMED = [
    ("two Host headers", b"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nHost: evil.example\r\n\r\n",
     "Duplicate 'Host' header found."),
    ("a NUL in a header name", b"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-A\x00: 1\r\n\r\n", "Invalid header"),
    ("a header line of 20000 bytes", b"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX: " + b"y" * 20000 + b"\r\n\r\n",
     "Got more than 8190 bytes"),
    ("a header line without a colon", b"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nNoColonHere\r\n\r\n", "Invalid header"),
    ("chunked and a length at once", b"POST /login HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 4\r\n"
                                     b"Transfer-Encoding: chunked\r\n\r\n0\r\n\r\n", "Transfer-Encoding"),
]


def test_malformed_http_costs_one_log_line_and_no_traceback(console_port, corpus_table, caplog):
    """aiohttp refuses what it cannot parse with 400; the coordinator's log says so in one line per
    request (here: none held back), instead of an ERROR with a traceback each."""
    port, app = console_port
    app.console.http_log.every_s = 0.0
    caplog.set_level(logging.DEBUG, logger="coordinator.console.http")
    for name, data, reason in MALFORMED:
        caplog.clear()
        with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
            s.sendall(data.replace(b"{port}", str(port).encode()))
            answer = b""
            while chunk := s.recv(65536):
                answer += chunk
        statuses = [int(line.split(b" ")[1]) for line in answer.split(b"\r\n") if line.startswith(b"HTTP/1.")]
        assert statuses[-1] == 400, (name, answer[:300])
        records = [r for r in caplog.records if r.name == "coordinator.console.http" and r.levelno >= logging.WARNING]
        assert len(records) == 1, (name, [r.getMessage() for r in records])
        line = records[0].getMessage()
        corpus_table("console log", name, line, statuses[-1])
        assert records[0].exc_info is None and "\n" not in line, (name, line)
        assert line.startswith("console: refused a malformed request from 127.0.0.1: ") and reason in line, (name, line)


def test_a_burst_of_malformed_requests_is_one_line_every_ten_seconds():
    from aiohttp.http_exceptions import BadHttpMessage

    from coordinator.console.service import HttpLog

    now = [0.0]
    seen = []

    class Sink(logging.Logger):
        def log(self, level, msg, *args, **kw):
            seen.append((level, msg % args, kw.get("exc_info")))

        def warning(self, msg, *args, **kw):
            self.log(logging.WARNING, msg, *args, **kw)

    log = HttpLog(Sink("sink"), clock=lambda: now[0])
    for i in range(50):
        log.exception("Error handling request from %s", "10.0.0.9", exc_info=BadHttpMessage("bad header"))
        now[0] += 0.5
    log.exception("Unhandled exception", exc_info=ValueError("a bug"))
    lines = [m for level, m, _ in seen if level == logging.WARNING]
    assert lines[0] == "console: refused a malformed request from 10.0.0.9: bad header"
    assert lines[1] == "console: refused a malformed request from 10.0.0.9: bad header (19 more since)"
    assert len(lines) == 3, lines
    assert seen[-1][0] == logging.ERROR and isinstance(seen[-1][2], ValueError), "other errors keep their traceback"
