"""The login form and the roles in a real browser (Debian's headless Chromium): a viewer logs in by
name and password and finds every action disabled, with their name and role shown; the rig token
logs in as an admin, whose page acts, lists the rig's users and adds one."""
from __future__ import annotations

import asyncio
import threading

import pytest
from selenium.webdriver.common.by import By

from bench.console import chromium, text_of, visible, wait_for
from coordinator import users
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.users import UserStore
from inprocess_coordinator import inprocess_coordinator

TOKEN = "b" * 32
PW = "viewer's password"


class _Coordinator:
    """A coordinator with its console on an event loop in a thread (no nodes: the page is what is tested)."""

    def __init__(self, rig_dir):
        self.rig_dir, self.url = rig_dir, ""
        self._ready, self._loop, self._stop = threading.Event(), None, None
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    async def _main(self):
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        async with inprocess_coordinator(Rig(self.rig_dir), TOKEN.encode(), console="127.0.0.1:0") as app:
            self.url = f"http://127.0.0.1:{app.console_port}/"
            self._ready.set()
            await self._stop.wait()

    def __enter__(self):
        self._thread.start()
        assert self._ready.wait(60), "the coordinator did not start"
        return self

    def __exit__(self, *exc):
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(60)


def _log_in(driver, name: str, secret: str) -> None:
    wait_for(lambda: visible(driver, "login-view"), 60, "the login form")
    for field, text in (("login-name", name), ("token", secret)):
        e = driver.find_element(By.ID, field)
        e.clear()
        e.send_keys(text)
    driver.find_element(By.ID, "login-button").click()


def _disabled(driver, ids: list[str]) -> dict[str, bool]:
    return {i: driver.execute_script(f"return document.getElementById('{i}').disabled;") for i in ids}


def test_a_viewers_page_acts_on_nothing_and_an_admin_sees_the_users(tmp_path, browser_ready, monkeypatch):
    monkeypatch.setattr(users, "SCRYPT_N", 1 << 10)
    rig_dir = init_rig(tmp_path / "rig", name="people", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)
    UserStore(rig_dir).add("vera", "viewer", PW)
    actions = ["stop", "blackout", "identify", "show-button", "play-button", "job-start"]
    with _Coordinator(rig_dir) as rig:
        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            _log_in(driver, "Vera", "wrong password")
            wait_for(lambda: "wrong name or password" in text_of(driver, "login-error"), 60, "the wrong password refused")
            _log_in(driver, "Vera", PW)
            wait_for(lambda: visible(driver, "main-view"), 60, "the console after the viewer's login")
            assert text_of(driver, "who") == "vera (viewer)"
            wait_for(lambda: all(_disabled(driver, actions).values()), 30,
                     f"a viewer's actions disabled: {_disabled(driver, actions)}")
            assert not _disabled(driver, ["logout"])["logout"]
            assert not driver.find_elements(By.ID, "people-panel") or not visible(driver, "people-panel")

            driver.find_element(By.ID, "logout").click()
            _log_in(driver, "", TOKEN)
            wait_for(lambda: text_of(driver, "who") == "token (admin)", 60, "the token's login as an admin")
            wait_for(lambda: not any(_disabled(driver, actions).values()), 30,
                     f"an admin's actions enabled: {_disabled(driver, actions)}")
            wait_for(lambda: visible(driver, "people-panel") and "vera" in text_of(driver, "people-users"), 60,
                     "the users listed for an admin")
            # an admin adds an operator from the page
            driver.find_element(By.ID, "people-name").send_keys("Pia")
            driver.find_element(By.ID, "people-password").send_keys(PW)
            driver.find_element(By.ID, "people-add-button").click()
            wait_for(lambda: "pia" in text_of(driver, "people-users"), 60, "the new user listed")
            assert UserStore(rig_dir).role_of("pia").value == "operator"
        finally:
            driver.quit()
