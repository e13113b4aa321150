"""The console's page in a real browser (headless Chromium through Debian's chromedriver) against a
coordinator in this process with no node: the page's own behaviour, in one page load.

* nothing of the control page shows under the login box (``main {display: grid}`` once beat the
  ``hidden`` attribute), and no picture the page holds hidden shows as a broken-image icon;
* a stopped show's line does not stay next to what the rig shows afterwards;
* the job form shows each option's label, unit, range and help, from the options' declarations;
* table points clicked on the camera view at a zoom other than 1 land in the table at the camera
  pixels under the pointer (the view is scaled down from the capture: the capture's size counts);
  a calibrate started with too few points is refused on the page, and the job's refusal is shown
  in the form's words;
* the cue panel lists the cues, GO (button and space bar) and a click on a row fire them through
  the console's routes, and the action log names who fired.

Waits are generous failure guards, never measurements.
"""
from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from bench.console import ConsoleRig, chromium, log_in, text_of, visible, wait_for
from coordinator.console.page_wording import for_the_page
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import Select

SLOTS = ["r0c0", "r0c1"]
CAPTURE = (1280, 720)           # wider than the console's view (960 px): the view is scaled down


class PageRig(ConsoleRig):
    """A ConsoleRig whose nodes are never started, with a folder camera of one still capture."""

    def __enter__(self) -> "PageRig":
        try:
            self.local.create()
            self._thread = threading.Thread(target=self._run, name="console-coordinator", daemon=True)
            self._thread.start()
            if not self._ready.wait(60) or self._error is not None:
                raise RuntimeError(f"the coordinator did not start: {self._error!r}")
        except BaseException:
            self.close()
            raise
        return self


def camera_folder(path) -> str:
    """folder:DIR holding one capture (each view opens the camera anew: always this one)."""
    path.mkdir()
    yy, xx = np.mgrid[0:CAPTURE[1], 0:CAPTURE[0]]
    img = np.stack([xx * 255 // CAPTURE[0], yy * 255 // CAPTURE[1], np.full_like(xx, 90)], -1).astype(np.uint8)
    assert cv2.imwrite(str(path / "000001.png"), img[:, :, ::-1])
    return f"folder:{path}"


def broken_images(driver) -> list[str]:
    """The ids (or alts) of pictures shown as a broken-image icon: displayed, with no picture."""
    return driver.execute_script(
        "return Array.from(document.images).filter(i => getComputedStyle(i).display !== 'none'"
        " && i.offsetParent !== null"
        " && (!i.getAttribute('src') || (i.complete && i.naturalWidth === 0))).map(i => i.id || i.alt);")


def click_again_if_redrawn(driver, selector: str) -> None:
    """Click an element of a table the page redraws when the rig's state changes (a fade ending):
    found again when it was redrawn between finding and clicking (up to 3 times)."""
    for attempt in range(3):
        try:
            driver.find_element("css selector", selector).click()
            return
        except StaleElementReferenceException:
            if attempt == 2:
                raise


@pytest.mark.slow
def test_the_page_tools_in_a_browser(tmp_path, browser_ready):
    with PageRig(tmp_path / "rig", SLOTS, posed=[], cameras=[camera_folder(tmp_path / "camera")]) as rig:
        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            wait_for(lambda: visible(driver, "login-view"), 60, "the login form")
            # the control page is not displayed under the login box
            assert driver.execute_script("return getComputedStyle(document.getElementById('main-view')).display;") \
                == "none"
            log_in(driver, rig.token)
            wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
            wait_for(lambda: driver.execute_script("return !document.getElementById('camera-img').hidden;"), 60,
                     "the camera view")
            wait_for(lambda: len(driver.find_elements("css selector", "#nodes tbody tr")) == 2, 60, "the node rows")
            assert broken_images(driver) == []

            # a show played and stopped: its line goes; what the rig shows stays
            asset = tmp_path / "card.png"
            assert cv2.imwrite(str(asset), np.full((90, 160, 3), 128, np.uint8))
            rig.call(lambda: rig.coord.asset_store.add(asset, name="card"))
            rig.call(lambda: rig.coord.play_asset("card", start_without=True))
            wait_for(lambda: "show " in text_of(driver, "show-state"), 60, "the show's line while it is on")
            rig.call(lambda: rig.coord.stop_all(blackout=True))
            wait_for(lambda: "blackout" in text_of(driver, "showing"), 60, "the blackout on the page")
            assert text_of(driver, "show-state") == ""

            # the job form: labels, units, ranges and help from the options' declarations
            Select(driver.find_element("id", "job-kind")).select_by_value("calibrate")
            wait_for(lambda: driver.find_elements("css selector", '[data-option="keep_going"]'), 60,
                     "the calibrate form")
            field = lambda name: driver.execute_script(  # noqa: E731
                "const d = document.querySelector(`[data-option='${arguments[0]}']`);"
                "return [d.querySelector('label').textContent, d.querySelector('.opt-help').textContent];", name)
            label, help_text = field("keep_going")
            assert label == "Keep going" and "go on with the other projectors when one fails" in help_text
            label, help_text = field("settle_s")
            assert label == "Settle (s)" and help_text.startswith("0–30 s · default 0.1 s · wait after every node")
            assert field("table_mm")[0] == "Table size (mm)"

            # points clicked on the camera view, zoomed in
            driver.execute_script("document.getElementById('pic-camera').scrollIntoView();"
                                  "window.__clicks = [];"
                                  "document.addEventListener('click', e => window.__clicks.push("
                                  "  [e.clientX, e.clientY, (() => { const r = document.getElementById('camera-img')"
                                  "  .getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()]),"
                                  " true);")
            driver.find_element("id", "calib-pick").click()
            for _ in range(2):
                driver.find_element("id", "calib-zoom-in").click()
            assert text_of(driver, "calib-zoom") == "2.3×"
            vp = driver.find_element("id", "camera-viewport")
            assert driver.execute_script("return document.getElementById('camera-img').getBoundingClientRect().width "
                                         "> arguments[0].clientWidth;", vp)
            for dx, dy in ((-120, -40), (35, 25), (140, 60)):
                ActionChains(driver).move_to_element_with_offset(vp, dx, dy).click().perform()
            wait_for(lambda: len(driver.find_elements("css selector", "#calib-points tbody tr")) == 3, 30,
                     "three points in the table")
            clicks = driver.execute_script("return window.__clicks;")[-3:]
            rows = driver.execute_script("return Array.from(document.querySelectorAll('#calib-points tbody tr'))"
                                         ".map(tr => [Number(tr.dataset.u), Number(tr.dataset.v)]);")
            for (cx, cy, (left, top, width, height)), (u, v) in zip(clicks, rows):
                # the pointer's fraction of the picture, times the capture's size; (0, 0) the first pixel's centre
                want = ((cx - left) / width * CAPTURE[0] - 0.5, (cy - top) / height * CAPTURE[1] - 0.5)
                assert abs(u - want[0]) <= 0.051 and abs(v - want[1]) <= 0.051, (u, v, want)
            # a mark dragged: its row follows, by the drag over the picture's scale
            scale = driver.execute_script(
                "return document.getElementById('camera-img').getBoundingClientRect().width;") / CAPTURE[0]
            before = rows[0]
            mark = driver.find_element("css selector", "#camera-marks circle[data-index='0']")
            ActionChains(driver).drag_and_drop_by_offset(mark, 30, 12).perform()
            u, v = driver.execute_script("const tr = document.querySelector('#calib-points tbody tr');"
                                         "return [Number(tr.dataset.u), Number(tr.dataset.v)];")
            assert len(driver.find_elements("css selector", "#calib-points tbody tr")) == 3, "a drag adds no point"
            slack = 1.5 / scale + 0.06          # the pointer's whole screen pixels, the table's 0.1 px
            assert abs(u - before[0] - 30 / scale) < slack and abs(v - before[1] - 12 / scale) < slack, (u, v, before)
            # a point deleted from its row; too few points are refused on the page, nothing sent
            driver.find_elements("css selector", "#calib-points button.calib-delete")[1].click()
            assert len(driver.find_elements("css selector", "#calib-points tbody tr")) == 2
            driver.find_element("id", "calib-start").click()
            wait_for(lambda: "click at least 4 table points" in text_of(driver, "calib-error"), 30,
                     "the page's refusal")
            assert rig.call(lambda: rig.coord.job_snapshot()) is None
            # the board way: the job's own refusal, in the page's words (test_page_wording.py: which words)
            driver.find_element("id", "calib-way-board").click()
            driver.find_element("id", "calib-start").click()
            wait_for(lambda: "calibrate failed" in text_of(driver, "job-line"), 60, "the calibrate job refused")
            error = rig.call(lambda: rig.coord.job_snapshot()["error"])
            assert for_the_page("calibrate", error) in text_of(driver, "job-line")

            # the cue panel: two cues added in its form, GO, the space bar, a jump
            for name in ("dark one", "dark two"):
                # the button is disabled until the page has the answer, which may come after the list shows
                wait_for(driver.find_element("id", "cue-save").is_enabled, 30, "the cue form's button enabled")
                driver.find_element("id", "cue-name").send_keys(name)
                Select(driver.find_element("id", "cue-kind")).select_by_value("blackout")
                driver.find_element("id", "cue-save").click()
                wait_for(lambda: name in text_of(driver, "cues"), 30,
                         f"cue {name!r} listed; the form says {text_of(driver, 'cue-form-error')!r}, the name field "
                         f"holds {driver.find_element('id', 'cue-name').get_attribute('value')!r}, the log "
                         f"{text_of(driver, 'actions')[:300]!r}")
            assert [c.name for c in rig.call(lambda: rig.coord.cue_state().cues)] == ["dark one", "dark two"]
            wait_for(driver.find_element("id", "cue-go").is_enabled, 30, "GO enabled")
            driver.find_element("id", "cue-go").click()
            wait_for(lambda: rig.call(lambda: rig.coord.cue_state().current) == 0, 30, "GO fired the first cue")
            mark = lambda k: driver.execute_script(  # noqa: E731
                "const td = document.querySelector(`#cues tr[data-index='${arguments[0]}'] .cue-mark`);"
                "return td ? td.textContent : '';", k)
            wait_for(lambda: mark(0).startswith("now") and mark(1) == "next", 30,
                     "the first cue current, the second next")
            driver.execute_script("document.getElementById('cues-panel').focus();")
            ActionChains(driver).send_keys(Keys.SPACE).perform()
            wait_for(lambda: rig.call(lambda: rig.coord.cue_state().current) == 1, 30, "the space bar fired GO")
            wait_for(lambda: mark(1).startswith("now"), 30, "the second cue marked current")
            click_again_if_redrawn(driver, "#cues tr[data-index='0'] td:nth-child(3)")
            wait_for(lambda: rig.call(lambda: rig.coord.cue_state().current) == 0, 30, "a click on a row jumped")
            wait_for(lambda: "cue jump" in text_of(driver, "actions"), 30, "the fires in the action log")
            # reordered, then one removed, from the rows' buttons
            names = lambda: [c.name for c in rig.call(lambda: rig.coord.cue_state().cues)]  # noqa: E731
            click_again_if_redrawn(driver, "#cues tr[data-index='0'] button.cue-down")
            wait_for(lambda: names() == ["dark two", "dark one"], 30, "the cues reordered")
            wait_for(driver.find_element("id", "cue-save").is_enabled, 30, "the cue form's button enabled")
            click_again_if_redrawn(driver, "#cues tr[data-index='1'] button.cue-remove")
            wait_for(lambda: names() == ["dark two"], 30, "a cue removed")
            assert "token" in text_of(driver, "actions")

            assert broken_images(driver) == []
            logs = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
            assert not [e for e in logs if "Content Security Policy" in e.get("message", "")], logs
        finally:
            driver.quit()
