"""The console's cue routes over HTTP, against a real coordinator in this process (no nodes: what is
checked here is the routes, the guard and the log; the pictures are tests/coordinator/test_cues_rig.py's):
a list is stored and refused in one line with nothing stored, GO and jump fire and land in the action
log under the user's name, /api/status carries the cue state, and a viewer may read but not fire."""
from __future__ import annotations

import asyncio
import contextlib
import json

import aiohttp

from coordinator.console import auth
from coordinator.console.audit import FILE_NAME
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.users import UserStore
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"k" * 32
PW = "a long password"


@contextlib.asynccontextmanager
async def console(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="cues", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32))
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app:
        yield app.coordinator, f"http://127.0.0.1:{app.console_port}"


async def login(s: aiohttp.ClientSession, base: str, name: str) -> dict:
    """Headers for a user's later requests (cookie, Origin, CSRF token)."""
    r = await s.post(base + "/login", json={"name": name, "password": PW}, headers={"Origin": base})
    assert r.status == 200, await r.text()
    body = await r.json()
    return {"Cookie": f"{auth.COOKIE}={r.cookies[auth.COOKIE].value}", "Origin": base,
            auth.CSRF_HEADER: body["csrf"]}


def log_lines(coord) -> list[dict]:
    f = coord.rig.path / FILE_NAME
    return [json.loads(line) for line in f.read_text().splitlines()] if f.exists() else []


def test_cue_routes_store_fire_and_log_who_acted(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, base), aiohttp.ClientSession(
                cookie_jar=aiohttp.DummyCookieJar()) as s:
            UserStore(coord.rig.path).add("otto", "operator", PW)
            UserStore(coord.rig.path).add("vera", "viewer", PW)
            op = await login(s, base, "otto")
            cues = {"cues": [{"id": "1", "name": "Dark", "kind": "blackout"},
                             {"id": "2", "name": "Dark again", "kind": "blackout", "fade_s": 0.5}]}
            r = await s.post(base + "/api/cues", json=cues, headers=op)
            assert r.status == 200 and (await r.json())["result"] == "2 cues stored"
            r = await s.post(base + "/api/cues", json={"cues": [{"id": "1", "kind": "still"}]}, headers=op)
            doc = await r.json()
            assert r.status == 400
            assert doc["error"] == "cue '1': a still cue needs a target (a still's name, e.g. content)"
            r = await s.get(base + "/api/cues", headers=op)
            state = await r.json()
            assert [c["id"] for c in state["cues"]] == ["1", "2"] and (state["current"], state["next"]) == (None, 0)

            r = await s.post(base + "/api/cues/go", headers=op, json={})
            assert r.status == 200 and (await r.json())["result"].startswith("cue 1 'Dark' (blackout) fires")
            r = await s.post(base + "/api/cues/jump", headers=op, json={"id": "9"})
            assert r.status == 400 and "no cue '9' in the list (cues: 1, 2)" in (await r.json())["error"]
            r = await s.post(base + "/api/cues/jump", headers=op, json={"id": "2"})
            assert r.status == 200, await r.text()
            snap = await (await s.get(base + "/api/status", headers=op)).json()
            assert snap["cues"]["current"] == 1 and snap["cues"]["next"] is None

            # a viewer reads the cues and may not fire them
            viewer = await login(s, base, "vera")
            assert (await s.get(base + "/api/cues", headers=viewer)).status == 200
            r = await s.post(base + "/api/cues/go", headers=viewer, json={})
            assert r.status == 403 and "vera is a viewer" in (await r.json())["error"]

            entries = log_lines(coord)      # each action's entry is written before its answer
            assert [e for e in entries if e["action"] == "cue fire"] == [], "one GO, one entry: the page's own"
            acted = [(e["who"], e["action"], e["ok"]) for e in entries if e["action"] != "login"]
            assert acted == [("otto", "cues", True), ("otto", "cues", False), ("otto", "cue go", True),
                             ("otto", "cue jump", False), ("otto", "cue jump", True), ("vera", "cues/go", False)], acted

    asyncio.run(go())
