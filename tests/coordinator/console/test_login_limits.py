"""The console's login limits: exponential backoff per address, a global budget of failures that
many addresses share, and the device cookie that keeps a browser which logged in before out of
both. Rules with an injected clock; then the same over HTTP against a running console."""
from __future__ import annotations

import asyncio
import contextlib
import math
from pathlib import Path

import aiohttp
import pytest

from coordinator.console import auth
from coordinator.rig import Rig, grid_slots, init_rig
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"t" * 32
#: a device cookies' key (the coordinator derives it from the rig token: Coordinator.token_key)
KEY = b"k" * 32

GUESS = {"token": "a-wrong-guess"}


@contextlib.asynccontextmanager
async def console(tmp_path: Path):
    """A coordinator with its console on 127.0.0.1 (no nodes): (the app, the console's base URL)."""
    rig = Rig(init_rig(tmp_path / "rig", name="limits", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32))
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app:
        yield app, f"http://127.0.0.1:{app.console_port}"


def client() -> aiohttp.ClientSession:
    # the default jar ignores cookies of IP-address hosts; these tests send and read cookies themselves
    return aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar())


class Clock:
    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_one_address_waits_longer_after_each_failure_up_to_the_cap():
    clock = Clock()
    lim = auth.LoginLimiter(clock=clock)
    waits = []
    for _ in range(9):
        assert lim.wait("10.0.0.5") == (0, ""), "each failure here is tried once its wait has passed"
        lim.failed("10.0.0.5")
        w, limit = lim.wait("10.0.0.5")
        waits.append(w)
        assert limit in ("", "address")
        clock.t += w
    # the first failure is free, then 1, 2, 4 ... seconds, capped
    assert waits == [0, 1, 2, 4, 8, 16, 30, 30, 30]
    assert lim.wait("10.0.0.6") == (0, ""), "another address is not held back"
    # an IPv6 host holds a whole /64: its addresses are one source; an IPv4-mapped one is its IPv4
    lim.failed("2001:db8:1:2::1")
    lim.failed("2001:db8:1:2::ffff")
    assert lim.wait("2001:db8:1:2:abcd::9") == (1, "address") and lim.wait("2001:db8:1:3::1") == (0, "")
    lim.failed("::ffff:10.0.0.5")
    assert lim.wait("10.0.0.5") == (30, "address")


def test_the_wait_counts_down_and_a_success_or_a_quiet_spell_forgets_the_failures():
    clock = Clock()
    lim = auth.LoginLimiter(clock=clock)
    for _ in range(4):
        clock.t += 60
        lim.failed("a")
    assert lim.wait("a") == (4, "address")
    clock.t += 1.5
    assert lim.wait("a") == (3, "address"), "the rest of the wait, rounded up"
    clock.t += 2.5
    assert lim.wait("a") == (0, "")
    lim.succeeded("a")
    lim.failed("a")
    assert lim.wait("a") == (0, ""), "after a success the next failure is free again"
    lim.failed("a")
    assert lim.wait("a") == (1, "address")
    clock.t += auth.FORGET_S
    lim.failed("a")
    assert lim.wait("a") == (0, ""), "failures older than FORGET_S are forgotten"


def test_many_addresses_together_get_no_more_tries_than_the_global_budget():
    """10,000 addresses, each trying every second for 10 minutes: the tries the console looks at
    stay within the budget plus its refill, and every refused one is told how long to wait."""
    clock = Clock()
    lim = auth.LoginLimiter(clock=clock)
    seconds, addresses = 600, 10_000
    tried = 0
    waits = set()
    for second in range(seconds):
        for i in range(0, addresses, 97):            # a changing tenth of them every second
            a = f"10.{(i + second) % 256}.{(i // 256) % 256}.{i % 251}"
            w, limit = lim.wait(a)
            if w == 0:
                tried += 1
                lim.failed(a)
            else:
                waits.add((limit, w))
        clock.t += 1.0
    ceiling = auth.GLOBAL_BUDGET + seconds * auth.GLOBAL_BUDGET / auth.GLOBAL_WINDOW_S
    assert tried <= ceiling, (tried, ceiling)
    assert tried >= 0.9 * ceiling, "the budget is spent, not closed for good"
    assert {limit for limit, _ in waits} <= {"global", "address"}
    assert max(w for limit, w in waits if limit == "global") <= math.ceil(auth.GLOBAL_WINDOW_S / auth.GLOBAL_BUDGET)


def test_once_a_guessing_pool_has_failed_a_clean_address_gets_the_next_turn():
    """50 guessing addresses, each trying 5 times a second for 10 minutes (as its backoff lets it):
    after each has failed once, a login from an address with no failure waits at most one refill
    (2 s); the guessers together still stay within the budget."""
    clock = Clock()
    lim = auth.LoginLimiter(clock=clock)
    pool = [f"172.16.0.{i}" for i in range(50)]
    rate = auth.GLOBAL_BUDGET / auth.GLOBAL_WINDOW_S
    tried, clean_waits = 0, []
    start = clock.t
    for step in range(600 * 5):
        for a in pool:
            if lim.wait(a)[0] == 0:
                tried += 1
                lim.failed(a)
        if step % 25 == 0 and clock.t - start > 60:       # every 5 s after the first minute
            clean_waits.append(lim.wait("10.1.2.3")[0])
        clock.t += 0.2
    assert all(w <= math.ceil(1 / rate) for w in clean_waits), clean_waits
    assert clean_waits.count(0) > 0.4 * len(clean_waits), clean_waits
    assert tried <= auth.GLOBAL_BUDGET + 600 * rate + 1, tried


def test_a_browser_with_a_device_cookie_gets_in_during_a_distributed_attack():
    clock = Clock()
    lim = auth.LoginLimiter(clock=clock)
    devices = auth.DeviceCookies(KEY)
    mine = devices.verify(devices.issue())
    assert mine
    for i in range(5000):                     # the budget is spent, by many addresses
        a = f"192.168.{i // 256}.{i % 256}"
        if lim.wait(a)[0] == 0:
            lim.failed(a)
    assert lim.wait("10.9.9.9")[1] == "global", "a browser without a device cookie waits its turn"
    assert lim.wait("192.168.0.1", mine) == (0, ""), "even from an address the guessers use"
    # the browser's own mistakes still cost it its own backoff, and nothing more
    lim.failed("10.9.9.9", mine)
    lim.failed("10.9.9.9", mine)
    assert lim.wait("10.9.9.9", mine) == (1, "device")
    clock.t += 1
    assert lim.wait("10.9.9.9", mine) == (0, "")


def test_device_cookies_cannot_be_forged_or_carried_to_another_token():
    devices = auth.DeviceCookies(KEY)
    value = devices.issue()
    device, mac = value.split(".")
    assert devices.verify(value) == device
    assert devices.issue(device) == value
    for bad in (None, "", device, f"{device}.", f"{device}.{mac[:-1]}", f"{device}x.{mac}", "é.é", "a" * 200,
                f".{mac}"):
        assert devices.verify(bad) is None, bad
    assert auth.DeviceCookies(b"the key of another rig's token..").verify(value) is None


def _post_login(s: aiohttp.ClientSession, base: str, body: dict, *, device: str | None = None):
    headers = {"Origin": base}
    if device:
        headers["Cookie"] = f"{auth.DEVICE_COOKIE}={device}"
    return s.post(base + "/login", json=body, headers=headers)


def test_login_limits_over_http(tmp_path, caplog):
    """A real console: a mistyping operator waits seconds, not a minute, and is told how long; a
    spent global budget holds back every browser but one that logged in before."""
    async def go():
        async with console(tmp_path) as (app, base), client() as s:
            clock = Clock()
            limiter = app.console.app.limiter
            limiter.clock = clock
            r = await _post_login(s, base, GUESS)
            assert r.status == 401, "the first mistake is free"
            r = await _post_login(s, base, GUESS)
            assert r.status == 401
            r = await _post_login(s, base, {"token": TOKEN.decode()})
            error = (await r.json())["error"]
            assert r.status == 429 and r.headers["Retry-After"] == "1", error
            assert error == "too many failed logins from 127.0.0.1: try again in 1 s"
            clock.t += 1
            r = await _post_login(s, base, {"token": TOKEN.decode()})
            assert r.status == 200, await r.text()
            device = r.cookies[auth.DEVICE_COOKIE]
            assert device["path"] == "/login" and device["httponly"] and device["samesite"] == "Strict"
            assert int(device["max-age"]) == auth.DEVICE_MAX_AGE_S
            assert app.console.app.devices.verify(device.value)

            # the global budget spent (as by many addresses): every other browser waits its turn
            limiter.budget, limiter.window_s = 3, 60.0
            limiter._tokens = None
            for i in range(3):
                clock.t += limiter.wait("127.0.0.1")[0]      # this address's own wait, no more
                assert (await _post_login(s, base, GUESS)).status == 401, i
            assert limiter.wait("127.0.0.1")[1] == "global"
            r = await _post_login(s, base, {"token": TOKEN.decode()})
            error = (await r.json())["error"]
            assert r.status == 429, error
            assert error.startswith("too many failed logins from many addresses: try again in "), error
            assert error == f"too many failed logins from many addresses: try again in {r.headers['Retry-After']} s"
            r = await _post_login(s, base, {"token": TOKEN.decode()}, device=device.value + "x")
            assert r.status == 429, "a forged device cookie counts for nothing"
            said = [r.getMessage() for r in caplog.records if "failed logins a minute" in r.getMessage()]
            assert said == ["console: more than 3 failed logins a minute from many addresses: logins from addresses "
                            "without a device cookie are tried once every 20 s in all, addresses that failed last; "
                            "browsers that logged in here before are not held back"], said
            r = await _post_login(s, base, {"token": TOKEN.decode()}, device=device.value)
            assert r.status == 200, await r.text()
            assert r.cookies[auth.DEVICE_COOKIE].value == device.value, "the same browser keeps its id"
            # the page sees it: wrong tokens and refused logins since start, new browsers held back now
            cookie = r.cookies[auth.COOKIE].value
            doc = await (await s.get(base + "/api/status", headers={"Cookie": f"{auth.COOKIE}={cookie}"})).json()
            logins = doc["logins"]
            assert (logins["failed"], logins["refused"], logins["held_back"]) == (5, 3, True), logins
            assert logins["budget_per_min"] == 3 and isinstance(logins["last_failed_at"], int)
            # its own mistakes: its own backoff, told in the same words
            for expected in (401, 401, 429):
                r = await _post_login(s, base, GUESS, device=device.value)
                assert r.status == expected
            assert (await r.json())["error"] == "too many failed logins from this browser: try again in 1 s"

    asyncio.run(go())


@pytest.mark.parametrize("count", [1, 2, 3, 7, 40])
def test_lock_s_is_the_stated_sequence(count):
    lim = auth.LoginLimiter()
    expected = 0.0 if count <= auth.FREE_FAILURES else min(auth.BACKOFF_CAP_S, 2.0 ** (count - 2))
    assert lim.lock_s(count) == expected
