"""The console's per-slot tools and health banner against a coordinator in this process and real
node processes: a test pattern and a solo asked over HTTP end up on the projectors (read back from
what each node rendered, not from the coordinator's flags), and in Chromium the layout's selection
highlights one slot, a slot without a pose is warned of as the command line does, Blackout asks
before it acts, and the banner names a lost node."""
from __future__ import annotations

import asyncio
import json

import aiohttp
import cv2
import numpy as np
import pytest
from selenium.webdriver.common.action_chains import ActionChains

from bench.console import ConsoleRig, chromium, click, log_in, text_of, visible, wait_for
from coordinator import test_patterns
from coordinator.rig import Content
from coordinator.unposed import unposed_warning
from shadowless.cli import main
from waits import wait_until

SLOTS = ["r0c0", "r0c1"]


class Page:
    """The console's HTTP API as a logged-in page uses it (token login, CSRF header, Origin)."""

    def __init__(self, rig: ConsoleRig):
        self.base = rig.url.rstrip("/")
        self.token = rig.token

    async def _post(self, path: str, doc: dict) -> tuple[int, dict]:
        async with aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
            r = await s.post(self.base + "/login", json={"token": self.token}, headers={"Origin": self.base})
            body = await r.json()
            headers = {"Cookie": f"shadowless_console={r.cookies['shadowless_console'].value}", "Origin": self.base,
                       "X-CSRF-Token": body["csrf"]}
            r = await s.post(self.base + path, json=doc, headers=headers)
            return r.status, await r.json()

    def post(self, path: str, doc: dict) -> tuple[int, dict]:
        return asyncio.run(self._post(path, doc))


def shown(snaps, slot: str) -> tuple[int, np.ndarray | None]:
    """(frame id, RGB picture) a node last rendered a still, from its snapshot files ((0, None): none yet)."""
    try:
        frame = json.loads((snaps / f"{slot}.json").read_text())["frame_id"]
        img = cv2.imread(str(snaps / f"{slot}.png"), cv2.IMREAD_UNCHANGED)
    except (OSError, ValueError, KeyError):
        return 0, None
    return frame, None if img is None else cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)


def wait_shows(snaps, slot: str, what: str, check) -> np.ndarray:
    return wait_until(lambda: shown(snaps, slot), lambda fi: fi[1] is not None and check(fi[1]),
                      what=f"{slot} showing {what}", timeout=120)[1]


@pytest.mark.slow
def test_patterns_solo_selection_confirmation_and_banner(tmp_path, browser_ready, capsys):
    with ConsoleRig(tmp_path / "rig", SLOTS, snapshots=True) as rig:
        rig.wait_live(timeout=240)
        snaps, (w, h) = rig.local.snapshot_dir, rig.local.output_size
        page = Page(rig)
        black = lambda img: img.max() == 0  # noqa: E731

        # a grid on r0c1 only: exactly the pattern there, black on r0c0
        status, body = page.post("/api/pattern", {"name": "grid", "slots": ["r0c1"]})
        assert status == 200 and body["ok"], body
        grid = test_patterns.test_pattern("grid", (w, h), label="r0c1")
        wait_shows(snaps, "r0c1", "the grid", lambda img: np.array_equal(img, grid))
        wait_shows(snaps, "r0c0", "black", black)
        assert "test pattern grid on r0c1" in body["result"]
        status, body = page.post("/api/pattern", {"name": "zebra"})
        assert status == 400 and "choose one of white, grid, crosshair, bars" in body["error"]

        # solo: white content on both, then only r0c0 lit, then both again
        white = Content(np.full((90, 160, 3), 255, np.uint8), name="white card")
        rig.call(lambda: rig.coord.show(white, persist=True))
        lit = lambda img: img.mean() > 100  # noqa: E731
        for s in SLOTS:
            wait_shows(snaps, s, "the white card", lit)
        status, body = page.post("/api/solo", {"slots": ["r0c0"]})
        assert status == 200 and body["result"].startswith("solo r0c0"), body
        wait_shows(snaps, "r0c1", "black (solo r0c0)", black)
        assert lit(shown(snaps, "r0c0")[1])
        status, body = page.post("/api/solo", {"slots": []})
        assert status == 200, body
        wait_shows(snaps, "r0c1", "the white card again", lit)
        status, body = page.post("/api/solo", {"slots": ["nope"]})
        assert status == 400 and "no slot 'nope'" in body["error"]

        # the command line's pattern and solo call the same methods
        common = ["--coordinator", f"127.0.0.1:{rig.local.port}", "--rig-dir", str(rig.local.rig_dir)]
        assert main(["pattern", "white", "--slots", "r0c0", *common]) == 0
        white_r0c0 = test_patterns.test_pattern("white", (w, h), label="r0c0")
        wait_shows(snaps, "r0c0", "white", lambda img: np.array_equal(img, white_r0c0))
        wait_shows(snaps, "r0c1", "black beside the pattern", black)
        capsys.readouterr()
        assert main(["solo", "nope", *common]) == 2
        err = capsys.readouterr().err
        assert "no slot 'nope'" in err and len(err.strip().splitlines()) == 1, err
        rig.call(lambda: rig.coord.show(white, persist=True))

        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            log_in(driver, rig.token)
            wait_for(lambda: visible(driver, "health"), 60, "the health banner")
            # the layout: selecting r0c0 in the list draws it on top, the other faded, one label
            wait_for(lambda: driver.find_elements("css selector", '#slot-list li[data-slot="r0c0"]'), 60, "the slot list")
            driver.find_element("css selector", '#slot-list li[data-slot="r0c0"]').click()
            # the pointer goes to the page's title: left where the click was, a footprint laid out
            # under it afterwards is hovered (drawn on top, labelled, never faded), which is right
            # for a pointer but not what this checks
            ActionChains(driver).move_to_element(driver.find_element("css selector", "header h1")).perform()
            classes = lambda: driver.execute_script(  # noqa: E731
                "return Object.fromEntries(Array.from(document.querySelectorAll('#layout g[data-slot]'))"
                ".map(g => [g.getAttribute('data-slot'), g.getAttribute('class')]));")
            wait_for(lambda: "selected" in classes().get("r0c0", "") and "hovered" not in " ".join(classes().values()),
                     60, f"r0c0 selected, nothing hovered: {classes()}")
            assert "faded" in classes()["r0c1"] and "selected" not in classes()["r0c1"], classes()
            labels = driver.execute_script(
                "return Array.from(document.querySelectorAll('#layout text.fp-name')).map(t => t.textContent);")
            assert labels == ["1 r0c0: live"], labels

            # a slot loses its pose: the page warns beside Show and Play with the command line's line
            assert not visible(driver, "unposed-warning")
            rig.call(lambda: rig.coord.update_slot("r0c1", pose=None))
            wait_for(lambda: visible(driver, "unposed-warning"), 60, "the warning of a slot without a pose")
            assert text_of(driver, "unposed-warning") == f"warning: {unposed_warning(['r0c1'])}"
            assert driver.find_elements("css selector", '#unposed .tile[data-slot="r0c1"]')

            # Blackout asks on the page first; only the confirmation acts
            click(driver, "blackout")
            wait_for(lambda: visible(driver, "confirm-bar"), 60, "the confirmation")
            assert driver.switch_to.active_element.get_attribute("id") == "confirm-cancel"
            assert "white card" in rig.call(lambda: rig.coord.status().showing)
            click(driver, "confirm-go")
            wait_for(lambda: rig.call(lambda: rig.coord.status().showing) == "black (blackout)", 60, "blackout")

            # a node killed: the banner turns to an alarm naming it, with how long ago
            rig.kill_node("r0c1")
            wait_for(lambda: driver.execute_script("return document.getElementById('health').dataset.level;")
                     == "alarm" and "r0c1 lost" in text_of(driver, "health"), 60,
                     f"the lost node on the banner: {text_of(driver, 'health')!r}")
            assert " s ago)" in text_of(driver, "health")
        finally:
            driver.quit()
