"""The operator console over HTTP, against a real coordinator in this process: login, CSRF and
Origin checks, cookie flags, security headers, escaping, and the actions calling through to the
rig and landing in the action log. (The login limits: test_login_limits.py; the Host check:
test_console_hosts.py.)"""
from __future__ import annotations

import asyncio
import contextlib
import json
import ssl
import struct
import subprocess
import zlib
from pathlib import Path

import aiohttp
import cv2
import numpy as np
import pytest

from coordinator.console import auth
from coordinator.console.audit import FILE_NAME
from coordinator.console.service import parse_listen
from coordinator.errors import CoordinatorError
from coordinator.rig import Content, HomographyPose, Rig, grid_slots, init_rig
from coordinator.app import CoordinatorApp
from coordinator.server import Coordinator
from inprocess_coordinator import inprocess_coordinator
from waits import wait_until_async

TOKEN = b"t" * 32
EVIL = "<script>alert(1)</script>"


@contextlib.asynccontextmanager
async def console(tmp_path: Path, *, tls: tuple[bytes, bytes] | None = None):
    rig = Rig(init_rig(tmp_path / "rig", name="web", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32))
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0", tls=tls) as app:
        scheme = "https" if tls else "http"
        yield app.coordinator, f"{scheme}://127.0.0.1:{app.console_port}"


def client(**kw) -> aiohttp.ClientSession:
    # the default jar ignores cookies of IP-address hosts; these tests read Set-Cookie themselves
    return aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar(), **kw)


async def login(s: aiohttp.ClientSession, base: str, token: str = TOKEN.decode()) -> tuple[dict, dict]:
    """(headers for later POSTs: cookie, Origin, CSRF token; the login's JSON)."""
    r = await s.post(base + "/login", json={"token": token}, headers={"Origin": base})
    assert r.status == 200, await r.text()
    body = await r.json()
    cookie = r.cookies[auth.COOKIE].value
    return {"Cookie": f"{auth.COOKIE}={cookie}", "Origin": base, auth.CSRF_HEADER: body["csrf"]}, body


def log_lines(coord: Coordinator) -> list[dict]:
    f = coord.rig.path / FILE_NAME
    return [json.loads(line) for line in f.read_text().splitlines()] if f.exists() else []


def png(w: int, h: int) -> bytes:
    img = np.zeros((h, w, 3), np.uint8)
    img[:, : w // 2] = (255, 0, 0)
    ok, data = cv2.imencode(".png", img)
    assert ok
    return data.tobytes()


def test_a_wrong_token_is_refused_and_logged(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            r = await s.post(base + "/login", json={"token": "not-the-token"}, headers={"Origin": base})
            assert r.status == 401
            assert "wrong token" in (await r.json())["error"]
            assert auth.COOKIE not in r.cookies
            r = await s.get(base + "/api/status")
            assert r.status == 401
            lines = log_lines(coord)
            assert lines and lines[-1]["action"] == "login" and lines[-1]["ok"] is False
            assert "not-the-token" not in (coord.rig.path / FILE_NAME).read_text(), "the log never holds a token"

    asyncio.run(go())


def test_cookie_flags_without_tls(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": base})
            cookie = r.headers["Set-Cookie"]
            assert cookie.startswith(f"{auth.COOKIE}=")
            flags = {p.strip().split("=")[0].lower(): p.strip() for p in cookie.split(";")[1:]}
            assert "httponly" in flags and flags["samesite"] == "SameSite=Strict" and flags["path"] == "Path=/"
            assert "secure" not in flags, "plain HTTP: a Secure cookie would never come back"
            assert (await r.json())["csrf"] not in cookie

    asyncio.run(go())


def test_https_and_a_secure_cookie_with_the_coordinators_certificate(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
                    "-days", "1", "-subj", "/CN=shadowless-test", "-addext", "subjectAltName=IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True)
    ctx = ssl.create_default_context(cafile=str(cert))

    async def go():
        async with console(tmp_path, tls=(cert.read_bytes(), key.read_bytes())) as (coord, base):
            assert base.startswith("https://")
            async with client(connector=aiohttp.TCPConnector(ssl=ctx)) as s:
                r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": base})
                assert r.status == 200
                for cookie in r.headers.getall("Set-Cookie"):      # the session's and the device cookie
                    assert "Secure" in cookie.split("; "), cookie
                assert {c.split("=")[0] for c in r.headers.getall("Set-Cookie")} == {auth.COOKIE, auth.DEVICE_COOKIE}
                # an http:// Origin is another origin than the https:// console
                headers, _ = await login(s, base)
                headers["Origin"] = base.replace("https://", "http://")
                r = await s.post(base + "/api/stop", headers=headers)
                assert r.status == 403

    asyncio.run(go())


def test_posts_without_the_csrf_token_are_refused(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            headers, _ = await login(s, base)
            before = coord.status().showing
            for bad in (None, "", "wrong"):
                h = dict(headers)
                if bad is None:
                    del h[auth.CSRF_HEADER]
                else:
                    h[auth.CSRF_HEADER] = bad
                r = await s.post(base + "/api/blackout", headers=h)
                assert r.status == 403, bad
                assert auth.CSRF_HEADER in (await r.json())["error"]
            assert coord.status().showing == before
            assert [e["action"] for e in log_lines(coord)] == ["login"], "refused requests never reach the rig"
            # no cookie at all: 401
            h = {k: v for k, v in headers.items() if k != "Cookie"}
            assert (await s.post(base + "/api/blackout", headers=h)).status == 401

    asyncio.run(go())


def test_posts_from_a_foreign_or_no_origin_are_refused(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            headers, _ = await login(s, base)
            for origin in ("http://evil.example", "null", base.replace("127.0.0.1", "localhost"), None):
                h = dict(headers)
                if origin is None:
                    del h["Origin"]
                else:
                    h["Origin"] = origin
                r = await s.post(base + "/api/stop", headers=h)
                assert r.status == 403, origin
                assert "Origin" in (await r.json())["error"]
            r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": "http://evil.example"})
            assert r.status == 403 and auth.COOKIE not in r.cookies
            assert all(e["action"] == "login" for e in log_lines(coord))

    asyncio.run(go())


def test_every_answer_carries_the_security_headers(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            answers = [await s.get(base + "/"), await s.get(base + "/static/console.js"),
                       await s.get(base + "/static/console.css"), await s.get(base + "/api/status"),
                       await s.get(base + "/static/nope.js"),
                       await s.post(base + "/login", json={"token": "x"}, headers={"Origin": base})]
            headers, _ = await login(s, base)
            answers.append(await s.get(base + "/api/status", headers={"Cookie": headers["Cookie"]}))
            for r in answers:
                csp = r.headers.get("Content-Security-Policy", "")
                assert "script-src 'self'" in csp and "unsafe-inline" not in csp, (r.url, csp)
                assert "frame-ancestors 'none'" in csp
                assert r.headers.get("X-Content-Type-Options") == "nosniff"
            assert [r.status for r in answers] == [200, 200, 200, 401, 404, 401, 200]
            async with s.get(base + "/api/events", headers={"Cookie": headers["Cookie"]}) as r:
                assert r.headers["Content-Type"].startswith("text/event-stream")
                assert "script-src 'self'" in r.headers["Content-Security-Policy"]

    asyncio.run(go())


def test_the_page_embeds_no_data_and_builds_no_html_from_strings(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            coord.refusals.record("ipv4:10.0.0.9:5000", EVIL, f"slot {EVIL!r} is not in rig <b>web</b>", coord.now())
            headers, _ = await login(s, base)
            files = {"image": png(64, 32)}
            form = aiohttp.FormData()
            form.add_field("image", files["image"], filename=f"{EVIL}.png", content_type="image/png")
            form.add_field("fit", "")
            r = await s.post(base + "/api/show", data=form, headers=headers)
            assert r.status == 200, await r.text()
            r = await s.post(base + "/api/gain", json={"slot": EVIL, "gain": 1.0}, headers=headers)
            assert r.status == 409
            texts = {}
            for path in ("/", "/static/console.js", "/static/console.css"):
                r = await s.get(base + path)
                texts[path] = await r.text()
                assert EVIL not in texts[path] and "<b>web</b>" not in texts[path]
            status = await s.get(base + "/api/status", headers={"Cookie": headers["Cookie"]})
            assert status.headers["Content-Type"].startswith("application/json")
            doc = await status.json()
            assert doc["refusals"][0]["slot"] == EVIL            # data, as JSON, for textContent
            assert any(e["params"].get("slot") == EVIL for e in doc["actions"])
            js = texts["/static/console.js"]
            for sink in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval("):
                assert sink not in js, sink
            assert "<script>" not in texts["/"].replace('<script src="/static/console.js" defer></script>', "")

    asyncio.run(go())


def test_stop_and_blackout_act_on_the_rig_and_are_logged(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            coord.show(Content(np.full((32, 64, 3), 200, np.uint8), name="grey"), persist=True)
            headers, body = await login(s, base)
            r = await s.post(base + "/api/blackout", headers=headers)
            assert r.status == 200 and (await r.json())["ok"]
            assert coord.status().showing == "black (blackout)"
            r = await s.post(base + "/api/stop", headers=headers)
            assert r.status == 200
            assert "grey" in coord.status().showing
            lines = log_lines(coord)
            assert [e["action"] for e in lines] == ["login", "blackout", "stop"]
            for e in lines:
                assert e["who"] == body["who"] and e["address"] == "127.0.0.1" and e["ok"] is True and e["time"]
            assert "grey" in lines[-1]["result"]
            # a job holding the projectors: the rig refuses, the console says why and logs it
            async with coord._job_lock:
                r = await s.post(base + "/api/stop", headers=headers)
            assert r.status == 409 and "job" in (await r.json())["error"]
            assert log_lines(coord)[-1]["ok"] is False

    asyncio.run(go())


def declared_png(width: int, height: int) -> bytes:
    """A valid PNG header declaring ``width`` x ``height`` grey pixels, with almost no pixel data."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + chunk(b"IEND", b""))


def test_gain_upload_and_play_go_through_the_coordinators_validation(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            headers, _ = await login(s, base)
            r = await s.post(base + "/api/gain", json={"slot": "r0c1", "gain": 0.5}, headers=headers)
            assert r.status == 200 and coord.rig.slots["r0c1"].gain == 0.5
            for gain in (99, -1, "x", None, True):
                r = await s.post(base + "/api/gain", json={"slot": "r0c1", "gain": gain}, headers=headers)
                assert r.status == 400, gain
            assert coord.rig.slots["r0c1"].gain == 0.5

            def form(data: bytes, name: str, fit: str = "") -> aiohttp.FormData:
                f = aiohttp.FormData()
                f.add_field("image", data, filename=name, content_type="application/octet-stream")
                f.add_field("fit", fit)
                return f

            r = await s.post(base + "/api/show", data=form(b"not an image at all", "notes.txt"), headers=headers)
            assert r.status == 400 and "notes.txt is not an image" in (await r.json())["error"]
            r = await s.post(base + "/api/show", data=form(png(40, 40), "square.png"), headers=headers)
            assert r.status == 400 and "choose how to fit" in (await r.json())["error"]
            r = await s.post(base + "/api/show", data=form(png(40, 40), "square.png", "contain"), headers=headers)
            assert r.status == 200, await r.text()
            assert "square.png" in coord.status().showing
            r = await s.post(base + "/api/show", data=form(png(40, 40), "square.png", "sideways"), headers=headers)
            assert r.status == 400
            for w, h in ((20000, 20000), (9000, 8000)):     # a few hundred bytes declaring gigabytes of pixels
                r = await s.post(base + "/api/show", data=form(declared_png(w, h), "bomb.png", "contain"),
                                 headers=headers)
                error = (await r.json())["error"]
                assert r.status == 400 and "at most 67 megapixels" in error, error
                assert f"bomb.png: its PNG header declares {w}x{h} pixels" in error, error
            r = await s.post(base + "/api/play", json={"asset": "nothing-like-it"}, headers=headers)
            assert r.status == 409 and "no asset matches" in (await r.json())["error"]
            ok = [(e["action"], e["ok"]) for e in log_lines(coord)]
            assert ok.count(("show", True)) == 1 and ok[-1] == ("play", False)
            assert "square.png" in coord.status().showing, "a refused upload changes nothing on the rig"

    asyncio.run(go())


def test_the_event_stream_pushes_changes_and_ends_with_the_session(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            coord.update_slot("r0c0", pose=HomographyPose(np.diag([0.5, 0.5, 1.0])))
            headers, _ = await login(s, base)
            async with s.get(base + "/api/events", headers={"Cookie": headers["Cookie"]}) as stream:
                events = []

                async def next_event():
                    name = data = None
                    while True:
                        line = (await stream.content.readline()).decode()
                        if line.startswith("event: "):
                            name = line[7:].strip()
                        elif line.startswith("data: "):
                            data = json.loads(line[6:])
                        elif line == "\n" and name:
                            return name, data

                async def until(pred):
                    while True:
                        ev = await next_event()
                        events.append(ev)
                        if pred(*ev):
                            return ev

                await asyncio.wait_for(until(lambda n, d: n == "snapshot"), 30)
                assert events[0][0] == "history"
                _, snap = events[-1]
                slots = {x["slot"]: x for x in snap["slots"]}
                # r0c0 outputs 32x32 px and its pose halves content: its footprint is 64x64 content px
                assert slots["r0c0"]["footprint"] == [[-1.0, -1.0], [63.0, -1.0], [63.0, 63.0], [-1.0, 63.0]]
                assert slots["r0c1"]["footprint"] is None and slots["r0c1"]["state"] == "expected"
                r = await s.post(base + "/api/blackout", headers=headers)
                assert r.status == 200
                await asyncio.wait_for(until(lambda n, d: n == "snapshot" and d["showing"] == "black (blackout)"), 30)
                await asyncio.wait_for(until(lambda n, d: n == "sample"), 30)
                await s.post(base + "/logout", headers=headers)
                await asyncio.wait_for(stream.content.read(), 30)     # the stream ends
            r = await s.get(base + "/api/status", headers={"Cookie": headers["Cookie"]})
            assert r.status == 401

    asyncio.run(go())


def test_idle_sessions_expire():
    now = [0.0]
    sessions = auth.Sessions(idle_s=60.0, clock=lambda: now[0])
    s = sessions.open("127.0.0.1")
    now[0] = 59.0
    assert sessions.get(s.sid) is s
    now[0] = 118.0
    assert sessions.get(s.sid) is s, "each use restarts the idle clock"
    now[0] = 179.0
    assert sessions.get(s.sid) is None and len(sessions) == 0


def test_listen_addresses():
    assert parse_listen("127.0.0.1:7680") == ("127.0.0.1", 7680)
    assert parse_listen("[::1]:0") == ("::1", 0)
    for bad in ("7680", "host:", "host:port", ":80", "h:70000"):
        with pytest.raises(CoordinatorError, match="HOST:PORT"):
            parse_listen(bad)


def test_the_coordinator_stops_with_an_event_stream_open(tmp_path):
    async def go():
        rig = Rig(init_rig(tmp_path / "rig", name="web", slots=["a"], width=32, height=32, content_width=32,
                           content_height=32))
        async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app:
            base = f"http://127.0.0.1:{app.console_port}"
            async with client() as s:
                headers, _ = await login(s, base)
                async with s.get(base + "/api/events", headers={"Cookie": headers["Cookie"]}) as stream:
                    assert (await stream.content.readline()).startswith(b"event: history")
                    await asyncio.wait_for(app.stop(), 60)
                    await asyncio.wait_for(stream.content.read(), 30)    # ended by the server

    asyncio.run(go())


def test_an_asset_of_the_store_plays_by_name(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            card = tmp_path / "card.png"
            card.write_bytes(png(64, 32))
            coord.distribution.store.add(card, name="card")
            assert await coord.refresh_assets()
            headers, _ = await login(s, base)
            doc = await (await s.get(base + "/api/status", headers={"Cookie": headers["Cookie"]})).json()
            assert [a["name"] for a in doc["assets"]] == ["card"]
            r = await s.post(base + "/api/play", json={"asset": "card", "loop": True}, headers=headers)
            assert r.status == 200, await r.text()
            st = coord.status().show
            assert st.name == "card" and st.loop and st.state in ("scheduled", "playing")
            r = await s.post(base + "/api/play", json={"asset": "card", "loop": "yes"}, headers=headers)
            assert r.status == 400
            assert [(e["action"], e["ok"]) for e in log_lines(coord)][-2:] == [("play", True), ("play", False)]

    asyncio.run(go())


# ---------------------------------------------------------------------- jobs
async def wait_job(s, base, headers, state_not="running", guard_s=120.0) -> dict:
    """The job's view once it is no longer ``state_not`` (the guard only bounds a broken run)."""
    async def job():
        return (await (await s.get(base + "/api/status", headers=headers)).json())["job"]

    return await wait_until_async(job, lambda j: j is not None and j["state"] != state_not,
                                  what=f"the job no longer {state_not}", timeout=guard_s)


def test_job_options_start_and_outcome(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            headers, _ = await login(s, base)
            opts = await (await s.get(base + "/api/job/options", headers=headers)).json()
            assert set(opts) >= {"calibrate", "alignment", "response", "transport", "compensate"}
            mode = next(f for f in opts["calibrate"] if f["name"] == "mode")
            assert mode["kind"] == "choice" and mode["choices"] == ["multiplexed", "sequential"] and mode["help"]

            r = await s.post(base + "/api/job", json={"kind": "levitate"}, headers=headers)
            assert r.status == 400 and "unknown job 'levitate'" in (await r.json())["error"]
            r = await s.post(base + "/api/job", json={"kind": "transport", "params": "fast"}, headers=headers)
            assert r.status == 400
            r = await s.post(base + "/api/job/cancel", headers=headers)
            assert r.status == 409 and "no job is running" in (await r.json())["error"]

            # no node is connected here: the job starts, fails, and the page shows why
            r = await s.post(base + "/api/job", json={"kind": "transport", "params": {"frames": 2}}, headers=headers)
            assert r.status == 200 and (await r.json())["result"] == "transport started"
            job = await wait_job(s, base, headers)
            assert job["state"] == "failed" and "no projector is connected" in job["error"]
            assert job["kind"] == "transport" and job["params"] == {"frames": 2}
            assert [ln["action"] for ln in log_lines(coord)][-1] == "job"

    asyncio.run(go())


def test_the_tracker_estimates_time_left_per_stage():
    from coordinator.jobs.context import Progress
    from coordinator.jobs.tracker import JobTracker

    now = [100.0]
    t = JobTracker(clock=lambda: now[0])
    t.begin("transport", {"frames": 1})
    t.event(Progress("dots", done=0, total=10))
    now[0] += 4.0
    t.event(Progress("dots", done=2, total=10))           # 2 per 4 s: 8 left -> 16 s
    assert t.snapshot()["eta_s"] == pytest.approx(16.0)
    t.event(Progress("solve", done=0, total=3))           # a new stage starts its own estimate
    assert t.snapshot()["eta_s"] is None
    t.event("a log line")
    t.end(result={"psnr_db": 40.1, "maps": [1, 2]})
    snap = t.snapshot()
    assert snap["state"] == "done" and snap["result"] == {"psnr_db": 40.1} and snap["log"][-1].endswith("a log line")
    # what a page shows of the parameters stays small, whatever a job was given
    t.begin("compensate_sequence", {"frames": ["x" * 100_000] * 300, "fps": 30.0, "slots": ["a", "b"],
                                    "table_points": [[0, 0, 1, 1]] * 4, "note": "y" * 5000, "extra": {"k": 1}})
    assert t.snapshot()["params"] == {"frames": "(300 items)", "fps": 30.0, "slots": ["a", "b"],
                                      "table_points": [[0, 0, 1, 1]] * 4, "note": "(5000 characters)",
                                      "extra": "(dict)"}


def test_a_taken_console_port_stops_the_start_unless_the_console_is_optional(tmp_path):
    """A console that cannot listen stops the coordinator's start with one line (the operator's
    browser would reach whatever holds the port); with ``console_optional`` the rig runs on and its
    status says the console is not served."""
    import socket

    async def go():
        holder = socket.socket()
        holder.bind(("127.0.0.1", 0))
        holder.listen(1)
        port = holder.getsockname()[1]
        try:
            rig = Rig(init_rig(tmp_path / "rig", name="web", slots=grid_slots(1, 1), width=32, height=32,
                               content_width=32, content_height=32))
            app = CoordinatorApp(rig, TOKEN, listen="127.0.0.1:0", advertise=False, console=f"127.0.0.1:{port}")
            with pytest.raises(CoordinatorError, match=f"cannot listen on 127.0.0.1:{port}: port {port} in use"):
                await app.start()
            # the refused start released the rig's lock
            async with inprocess_coordinator(rig, TOKEN, console=f"127.0.0.1:{port}", console_optional=True) as app:
                assert app.port and app.console_port == 0
                st = app.coordinator.status()
                assert st.rig_name == "web" and st.console == f"NOT SERVED (port {port} in use)"
        finally:
            holder.close()

    asyncio.run(go())


def test_each_kind_of_refusal_gets_its_http_status(tmp_path):
    """A Refusal from the rig answers with its kind's status (and its message, logged as refused);
    a rig refusing a credential answers 403, never the 401 that makes the page ask for a login."""
    from coordinator.errors import Refusal, RefusalKind

    expected = {RefusalKind.INVALID: 400, RefusalKind.NOT_FOUND: 404, RefusalKind.CONFLICT: 409,
                RefusalKind.UNAUTHENTICATED: 403, RefusalKind.FAILED_PRECONDITION: 409,
                RefusalKind.RESOURCE_EXHAUSTED: 429, RefusalKind.DEADLINE_EXCEEDED: 408,
                RefusalKind.UNAVAILABLE: 503}
    assert set(expected) == set(RefusalKind), "every kind has its status here"

    async def go():
        async with console(tmp_path) as (coord, base), client() as s:
            headers, _ = await login(s, base)
            for kind, status in expected.items():
                def refuse(*, blackout: bool = False, kind=kind):
                    raise Refusal(kind, f"refused as {kind.value}")
                coord.stop_all = refuse
                r = await s.post(base + "/api/blackout", headers=headers)
                body = await r.json()
                assert (r.status, body["ok"], body["error"]) == (status, False, f"refused as {kind.value}"), kind
                assert log_lines(coord)[-1]["ok"] is False
            # the console's own session is untouched by the rig's refusals
            r = await s.get(base + "/api/session", headers={"Cookie": headers["Cookie"]})
            assert r.status == 200

    asyncio.run(go())
