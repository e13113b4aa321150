"""The operator console in a real browser: headless Chromium (Debian's chromium and
chromedriver, through Selenium) against a coordinator in this process and real node
processes. Waits are generous failure guards, never measurements (`bench/console.py` times)."""
from __future__ import annotations

import socket

import grpc
import numpy as np
import pytest

from bench.console import (ConsoleRig, all_shown, chromium, click, log_in, page_gains, page_states,
                           text_of, visible, wait_for)
from coordinator.rig import Content
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import Select
from waits import wait_until

EVIL = "<script>document.title='pwned'</script><img src=x onerror=\"document.title='pwned'\">"
SLOTS = ["r0c0", "r0c1"]


def type_into(field, text: str) -> None:
    """Replace a field's text as a person does: focused first (the page leaves a focused field alone
    when a snapshot arrives), then select all and type. Checked, and typed again (up to 3 times)
    when a keystroke went astray: the field must hold exactly ``text`` before anything is clicked."""
    for _ in range(3):
        field.click()
        field.send_keys(Keys.CONTROL, "a")
        field.send_keys(text)
        if field.get_attribute("value") == text:
            return
    raise AssertionError(f"could not type {text!r} into the field: it holds {field.get_attribute('value')!r}")


@pytest.fixture
def silent_camera():
    """A camera address that accepts connections and never answers: a job capturing from it waits."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(8)
    yield f"room://127.0.0.1:{s.getsockname()[1]}"
    s.close()


@pytest.mark.slow
def test_the_console_in_a_browser(tmp_path, browser_ready, silent_camera):
    with ConsoleRig(tmp_path / "rig", SLOTS, posed=["r0c0"], cameras=[silent_camera]) as rig:
        rig.wait_live(timeout=240)
        grey = Content(np.full((90, 160, 3), 180, np.uint8), name="grey card")
        rig.call(lambda: rig.coord.show(grey, persist=True))
        rig.call(lambda: rig.coord.refusals.record("ipv4:10.9.9.9:4242", EVIL, f"slot {EVIL} is not in this rig",
                                                   rig.coord.now()))
        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            # a wrong token is refused, and the page stays on the login form
            log_in(driver, "certainly-not-the-token")
            wait_for(lambda: "wrong token" in text_of(driver, "login-error"), 60, "the wrong token refused")
            assert not visible(driver, "main-view")

            log_in(driver, rig.token)
            wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
            wait_for(lambda: all_shown(driver, SLOTS, "live"), 120, f"every node live, page shows {page_states(driver)}")
            # the layout: r0c0's footprint in the SVG, r0c1 (no pose) as a tile beside it, both live
            classes = driver.execute_script(
                "return [document.querySelector('#layout g[data-slot=\"r0c0\"] polygon').getAttribute('class'),"
                " document.querySelector('#unposed [data-slot=\"r0c1\"]').getAttribute('class')];")
            assert "state-live" in classes[0] and "state-live" in classes[1], classes
            assert "grey card" in text_of(driver, "showing")
            # the wrong token above, counted where the operator sees refusals
            wait_for(lambda: "1 wrong token since the coordinator started" in text_of(driver, "logins"), 60,
                     f"the wrong token counted on the page, which says {text_of(driver, 'logins')!r}")
            # a Hello of bytes that are no Hello, from a peer without the token: counted on the page
            with grpc.insecure_channel(f"127.0.0.1:{rig.app.port}") as ch:
                with pytest.raises(grpc.RpcError):
                    ch.unary_unary("/shadowless.v1.NodeLink/Hello")(b"\xff" * 1000, timeout=30)
            wait_for(lambda: "0 refused over the budget, 1 malformed" in text_of(driver, "before-auth"), 60,
                     f"the malformed call counted on the page, which says {text_of(driver, 'before-auth')!r}")

            # a hostile name from a refusal is shown as text, never run or parsed
            wait_for(lambda: EVIL in text_of(driver, "refusals"), 60, "the refusal listed")
            # (the page's own pictures are images too: look for what the hostile name would have made)
            assert driver.execute_script(
                "return document.querySelectorAll('main script, main [onerror], main img[src=\"x\"]').length;") == 0
            assert driver.title != "pwned"

            # Blackout and Stop act on the rig, once confirmed on the page
            click(driver, "blackout")
            wait_for(lambda: visible(driver, "confirm-bar"), 60, "the blackout's confirmation")
            click(driver, "confirm-go")
            wait_for(lambda: rig.call(lambda: rig.coord.status().showing) == "black (blackout)", 60, "blackout on the rig")
            wait_for(lambda: "blackout" in text_of(driver, "showing"), 60, "blackout on the page")
            click(driver, "stop")
            wait_for(lambda: visible(driver, "confirm-bar"), 60, "the stop's confirmation")
            click(driver, "confirm-go")
            wait_for(lambda: "grey card" in rig.call(lambda: rig.coord.status().showing), 60, "the content restored")
            wait_for(lambda: "grey card" in text_of(driver, "showing"), 60, "the content on the page")

            # a slot's gain set on the page reaches the rig; a bad one is refused beside its field
            gain = driver.find_element("css selector", '#nodes tr[data-slot="r0c1"] input.gain')
            type_into(gain, "0.75")
            driver.find_element("css selector", '#nodes tr[data-slot="r0c1"] button.gain-set').click()
            wait_for(lambda: rig.call(lambda: rig.coord.rig.slots["r0c1"].gain) == 0.75, 60, "gain 0.75 on the rig")
            # the button is disabled until the page has the answer, which may come after the rig changed
            set_button = driver.find_element("css selector", '#nodes tr[data-slot="r0c1"] button.gain-set')
            wait_for(set_button.is_enabled, 60, "the Set button enabled again")
            type_into(gain, "99")
            driver.find_element("css selector", '#nodes tr[data-slot="r0c1"] button.gain-set').click()
            err = lambda: driver.execute_script(  # noqa: E731
                "return document.querySelector('#nodes tr[data-slot=\"r0c1\"] .error').textContent;")
            try:
                wait_for(lambda: "gain must be" in err(), 60, "the refused gain explained beside its field")
            except TimeoutError as exc:  # say what the page and the rig hold instead
                raise AssertionError(f"{exc}; beside the field: {err()!r}, field {page_gains(driver)['r0c1']!r}, "
                                     f"rig gain {rig.call(lambda: rig.coord.rig.slots['r0c1'].gain)}, "
                                     f"action log: {text_of(driver, 'actions')[-400:]!r}") from exc
            assert rig.call(lambda: rig.coord.rig.slots["r0c1"].gain) == 0.75
            assert page_gains(driver)["r0c1"] == "99", "the operator's input is kept while it is being corrected"

            # the action log on the page
            wait_for(lambda: all(a in text_of(driver, "actions") for a in ("blackout", "stop", "gain", "refused")), 60,
                     "the actions in the log")

            # a job started from the page with one of its options, followed there, and cancelled there
            Select(driver.find_element("id", "job-kind")).select_by_value("calibrate")
            wait_for(lambda: driver.find_elements("id", "job-opt-table_points"), 60, "the calibrate form")
            driver.find_element("id", "job-opt-table_points").send_keys(
                "[[0, 0, 10, 10], [100, 0, 200, 10], [100, 100, 200, 200], [0, 100, 10, 200]]")
            driver.find_element("id", "job-start").click()
            wait_for(lambda: "calibrate running" in text_of(driver, "job-line"), 60, "the job running on the page")
            job = rig.call(lambda: rig.coord.jobs.snapshot())
            assert job["state"] == "running" and len(job["params"]["table_points"]) == 4
            driver.find_element("id", "job-cancel").click()
            wait_for(lambda: "calibrate cancelled" in text_of(driver, "job-line"), 60, "the job cancelled on the page")
            assert rig.call(lambda: rig.coord.jobs.snapshot()["state"]) == "cancelled"

            # a node killed turns lost on the page
            rig.kill_node("r0c1")
            wait_for(lambda: page_states(driver).get("r0c1") == "lost", 60, "r0c1 lost")
            assert page_states(driver)["r0c0"] == "live"

            shot = tmp_path / "console.png"
            assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
            print(f"console screenshot: {shot}")
            logs = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
            assert not [e for e in logs if "Content Security Policy" in e.get("message", "")], logs
        finally:
            driver.quit()


@pytest.mark.slow
def test_identify_and_stop_act_on_the_nodes(tmp_path):
    """Identify from the console: every node shows exactly its own name card (read back from what
    each node rendered), and Stop dismisses it."""
    import asyncio
    import json

    import aiohttp
    import cv2

    from coordinator.identify import identify_cards

    with ConsoleRig(tmp_path / "rig", SLOTS, snapshots=True) as rig:
        rig.wait_live(timeout=240)
        snaps = rig.local.snapshot_dir

        def shown(slot: str) -> tuple[str, np.ndarray | None]:
            meta, png = snaps / f"{slot}.json", snaps / f"{slot}.png"
            try:
                tag = json.loads(meta.read_text())["tag"]
                img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            except (OSError, ValueError, KeyError):
                return "", None
            return tag, None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

        async def post(path: str) -> dict:
            base = rig.url.rstrip("/")
            async with aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
                r = await s.post(base + "/login", json={"token": rig.token}, headers={"Origin": base})
                body = await r.json()
                headers = {"Cookie": f"shadowless_console={r.cookies['shadowless_console'].value}", "Origin": base,
                           "X-CSRF-Token": body["csrf"]}
                r = await s.post(base + path, headers=headers)
                return await r.json()

        assert asyncio.run(post("/api/identify"))["ok"]
        w, h = rig.local.output_size
        for slot in SLOTS:
            _, img = wait_until(lambda: shown(slot), lambda tagged: tagged[0] == "show:identify",
                                what=f"{slot} showing its name card", timeout=120)
            np.testing.assert_array_equal(img, identify_cards({s: (w, h) for s in SLOTS})[slot])
        assert rig.call(lambda: rig.coord.status().showing) == "slot names (identify)"
        assert asyncio.run(post("/api/stop"))["ok"]
        wait_for(lambda: rig.call(lambda: rig.coord.status().showing) == "black (blackout)", 60, "identify dismissed")
