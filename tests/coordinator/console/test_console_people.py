"""People, not sessions: console logins by name and password with roles, against a real coordinator
in this process. A viewer sees and is refused every action (403, one line, nothing changed, the
refusal logged with their name); an operator acts and the action log names them; a role changed,
a user removed or a password set again on the command line's side (the store) holds at the next
request; only admins list and manage the users; failed logins are limited per user name across
addresses."""
from __future__ import annotations

import asyncio
import json

import aiohttp
import pytest

from coordinator import users
from coordinator.console import auth
from coordinator.console.audit import FILE_NAME
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.users import UserStore
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"p" * 32
PW = "a long password"


@pytest.fixture(autouse=True)
def cheap_hashes(monkeypatch):
    monkeypatch.setattr(users, "SCRYPT_N", 1 << 10)     # the parameters travel with each hash


async def _login(s: aiohttp.ClientSession, base: str, body: dict, status: int = 200) -> tuple[dict, dict]:
    r = await s.post(base + "/login", json=body, headers={"Origin": base})
    doc = await r.json()
    assert r.status == status, doc
    if status != 200:
        return {}, doc
    return {"Cookie": f"{auth.COOKIE}={r.cookies[auth.COOKIE].value}", "Origin": base,
            auth.CSRF_HEADER: doc["csrf"]}, doc


def test_roles_decide_who_acts_and_the_log_names_them(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="people", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)
    store = UserStore(rig_dir)
    store.add("vera", "viewer", PW)
    store.add("Otto", "operator", PW)
    log_file = rig_dir / FILE_NAME

    def entries() -> list[dict]:
        return [json.loads(line) for line in log_file.read_text().splitlines()]

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), TOKEN, console="127.0.0.1:0") as app:
            base = f"http://127.0.0.1:{app.console_port}"
            coord = app.coordinator
            async with aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
                viewer, doc = await _login(s, base, {"name": "Vera", "password": PW})
                assert (doc["who"], doc["role"]) == ("vera", "viewer")
                r = await s.get(base + "/api/session", headers=viewer)
                assert (await r.json())["role"] == "viewer"
                r = await s.get(base + "/api/status", headers=viewer)
                assert r.status == 200, "a viewer sees everything"
                showing = coord.status().showing
                r = await s.post(base + "/api/blackout", headers=viewer)
                err = (await r.json())["error"]
                assert r.status == 403 and "vera is a viewer" in err and "operator" in err and "\n" not in err
                assert coord.status().showing == showing, "a refused action changes nothing"
                assert entries()[-1]["who"] == "vera" and entries()[-1]["ok"] is False
                r = await s.get(base + "/api/users", headers=viewer)
                assert r.status == 403

                operator, doc = await _login(s, base, {"name": "otto", "password": PW})
                r = await s.post(base + "/api/blackout", headers=operator)
                assert r.status == 200, await r.text()
                e = entries()[-1]
                assert (e["who"], e["action"], e["ok"]) == ("otto", "blackout", True)
                assert coord.status().showing != showing
                r = await s.get(base + "/api/users", headers=operator)
                assert r.status == 403 and "needs the admin role" in (await r.json())["error"]

                # what the command line changes holds at the next request, without a restart
                store.set_role("vera", "operator")
                r = await s.post(base + "/api/stop", headers=viewer)
                assert r.status == 200 and entries()[-1]["who"] == "vera"
                store.remove("otto")
                r = await s.get(base + "/api/status", headers=operator)
                assert r.status == 401 and "log in again" in (await r.json())["error"]

                admin, doc = await _login(s, base, {"token": TOKEN.decode()})
                assert (doc["who"], doc["role"]) == ("token", "admin")
                r = await s.get(base + "/api/users", headers=admin)
                listing = await r.json()
                assert [(u["name"], u["role"]) for u in listing["users"]] == [("vera", "operator")]
                assert "hash" not in json.dumps(listing)
                assert {x["who"] for x in listing["sessions"]} == {"vera", "token"}

                # an admin manages the users from the page's side too; nobody else may
                for path, body in (("/api/users", {"name": "Pia", "role": "operator", "password": PW}),
                                   ("/api/users/role", {"name": "pia", "role": "viewer"})):
                    r = await s.post(base + path, json=body, headers=viewer)
                    assert r.status == 403, "an operator is no admin"
                    r = await s.post(base + path, json=body, headers=admin)
                    assert r.status == 200, await r.text()
                assert store.role_of("pia").value == "viewer" and PW not in log_file.read_text()
                r = await s.post(base + "/api/users", json={"name": "pia", "role": "admin", "password": PW}, headers=admin)
                assert r.status == 400 and "exists already" in (await r.json())["error"]
                r = await s.post(base + "/api/users/remove", json={"name": "pia"}, headers=admin)
                assert r.status == 200 and store.role_of("pia") is None
                assert entries()[-1]["who"] == "token" and entries()[-1]["action"] == "remove user"

                # wrong passwords and unknown names: one answer for both, logged without the password
                _, doc = await _login(s, base, {"name": "vera", "password": "not it at all"}, status=401)
                assert doc["error"].startswith("wrong name or password")
                assert "not it at all" not in log_file.read_text()
                # a new password ends the sessions opened with the old one
                store.set_password("vera", PW + "!")
                r = await s.get(base + "/api/status", headers=viewer)
                assert r.status == 401
                r = await s.post(base + "/logout", headers=admin)
                assert r.status == 200

    asyncio.run(go())


def test_failed_logins_are_limited_per_name_across_addresses():
    now = [0.0]
    lim = auth.LoginLimiter(clock=lambda: now[0])
    lim.failed("10.0.0.1", name="alice")
    lim.failed("10.0.0.2", name="alice")
    # a third address trying alice waits for the name's backoff; the same address for another name does not
    wait, limit = lim.wait("10.0.0.3", name="alice")
    assert wait >= 1 and limit == "name"
    assert lim.wait("10.0.0.3", name="bob") == (0, "")
    # a browser that logged in before is limited by its own failures only
    assert lim.wait("10.0.0.3", device="d1", name="alice") == (0, "")
    now[0] += lim.lock_s(2) + 0.1
    assert lim.wait("10.0.0.3", name="alice") == (0, "")
    lim.succeeded("10.0.0.3", name="alice")
    lim.failed("10.0.0.4", name="alice")
    assert lim.wait("10.0.0.5", name="alice") == (0, ""), "a success starts the name again from nothing"
