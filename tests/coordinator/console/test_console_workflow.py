"""The whole page-only workflow in the virtual room, in a real browser (issue 38's "what it must reach").

A room in a thread of this process (2x2 projectors of the reference array, at a small resolution),
four node processes showing into it, a coordinator with its console whose camera is the room's,
and headless Chromium. Everything the operator does goes through the page:

* an operator made with ``shadowless rig user add`` logs in by name and password;
* the table's marks are clicked on the camera view where the room's camera sees them (the room's
  geometry says where) and their millimetres typed beside them: the page's table holds those camera
  pixels; calibrate runs from the view's button, alignment, response and transport from the job
  form, each ending done (alignment: every projector within a pixel);
* an image uploaded and shown is what the camera view shows afterwards (correlated with what the
  room's geometry says the camera should see), and still is after compensate (started from the
  form with *evaluate*: the page's scores say the compensated capture is closer to the target);
* a three-cue list built in the cue panel (blackout; the rig's content with a 2 s crossfade; a grid
  pattern) and fired with GO: each node's own rendering shows black, then the picture it showed
  before (and mixed pictures on the way), then exactly the labelled grid;
* a node killed turns the health banner to an alarm naming it;
* a viewer's GO (the space bar on the cue panel) is refused on the page in one line, changing nothing.

Waits are generous failure guards, never measurements.
"""
from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from bench.compensation_room import demo_image
from bench.console import chromium, text_of
from bench.console_workflow import (CONTENT, MARKS_MM, SLOTS, RoomConsoleRig, Workflow, correlation, expected_view,
                                    mark_pixels, small_room)
from coordinator import test_patterns
from shadowless.cli import main
from sim.wire.service import RoomServerThread
from waits import wait_until

OPERATOR, VIEWER = ("ola", "ola's password"), ("vera", "vera's password")


def add_user(rig_dir, name: str, role: str, password: str, tmp_path) -> None:
    """``shadowless rig user add NAME --role ROLE`` with the password from a file."""
    f = tmp_path / f"{name}.pw"
    f.write_text(password + "\n")
    assert main(["rig", "user", "add", name, "--role", role, "--password-file", str(f), "--rig-dir", str(rig_dir)]) == 0


@pytest.mark.slow
def test_the_whole_workflow_from_the_page_in_the_virtual_room(tmp_path, browser_ready):
    room = small_room()
    image = demo_image(CONTENT)
    upload = tmp_path / "astronaut.png"
    assert cv2.imwrite(str(upload), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    with RoomServerThread(room) as server, \
            RoomConsoleRig(tmp_path / "rig", server.address, room.projector_size(SLOTS[0])) as rig:
        rig_dir = rig.local.rig_dir
        add_user(rig_dir, OPERATOR[0], "operator", OPERATOR[1], tmp_path)
        add_user(rig_dir, VIEWER[0], "viewer", VIEWER[1], tmp_path)
        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            page = Workflow(rig, driver)
            page.log_in(*OPERATOR)
            wait_until(lambda: text_of(driver, "who"), lambda w: w == "ola (operator)", what="who is logged in",
                       timeout=30)
            page.wait_live()

            # the table's marks clicked where the room's camera sees them, their mm typed beside them
            truth = mark_pixels(room)
            picked = page.pick_points(truth)
            assert len(picked) == len(MARKS_MM)
            assert np.abs(np.array(picked) - truth).max() < 0.8, (picked, truth)   # a screen pixel, in camera px
            job = page.calibrate_from_view()
            assert job["state"] == "done", job["error"]
            assert rig.call(lambda: all(rig.coord.rig.slots[s].pose is not None for s in SLOTS))

            job = page.run_job("alignment")
            assert job["state"] == "done", job["error"]
            rms = wait_until(page.alignment_rms, lambda r: set(r) == set(SLOTS), what="the alignment table",
                             timeout=60)
            assert max(rms.values()) < 1.0, rms
            for kind in ("response", "transport"):
                job = page.run_job(kind)
                assert job["state"] == "done", (kind, job["error"])

            # an image uploaded and shown: the camera view shows it where the room says it lands
            t = time.time()
            page.show_image(upload, "astronaut.png")
            view = page.camera_view(after=t + 0.5)
            expected, inside = expected_view(room, image, (view.shape[1], view.shape[0]))
            seen = lambda: correlation(page.camera_view(after=t + 0.5), expected, inside)  # noqa: E731
            wait_until(seen, lambda r: r > 0.8, what="the image in the camera view (correlation)", timeout=60)

            # compensate the image the rig shows, with the before/after captures
            job = page.run_job("compensate", ticks=("evaluate",))
            assert job["state"] == "done", job["error"]
            scores = wait_until(page.compensation_scores, lambda q: "none" in q and "ours" in q,
                                what="the compensation's scores in Pictures", timeout=60)
            assert scores["ours"][0] > scores["none"][0] + 0.5, scores     # PSNR (dB): closer to the target
            wait_until(lambda: text_of(driver, "showing"), lambda t: "compensated" in t,
                       what="the compensated image shown", timeout=30)
            t = time.time()
            wait_until(seen, lambda r: r > 0.8, what="the compensated image in the camera view", timeout=60)
            content = {s: wait_until(lambda: rig.shown(s), lambda fi: fi[1] is not None, what=f"{s}'s picture",
                                     timeout=60)[1] for s in SLOTS}

            # three cues from the panel, GO through them: black, the content crossfaded in, a grid
            page.add_cue("Preset", "blackout")
            page.add_cue("Opening", "still", "content", fade_s=2.0)
            page.add_cue("Focus grid", "pattern", "grid")
            assert [c.kind for c in rig.call(lambda: rig.coord.cue_state().cues)] == ["blackout", "still", "pattern"]
            assert page.cue_go() == 0
            for s in SLOTS:
                wait_until(lambda: rig.shown(s)[1], lambda img: img is not None and img.max() <= 2,
                           what=f"{s} black after the first cue", timeout=60)
            dark = {s: rig.shown(s)[0] for s in SLOTS}
            assert page.cue_go() == 1
            mixed: set[str] = set()

            def faded_in() -> bool:
                """Every node ends on the picture it showed before the cues; any step seen between black
                and that picture is noted (the fade's steps come 30 a second)."""
                done = True
                for s in SLOTS:
                    frame, img = rig.shown(s)
                    if img is None or frame == dark[s]:
                        done = False
                        continue
                    if 2 < img.mean() < content[s].mean() - 2:
                        mixed.add(s)
                    done = done and np.abs(img.astype(int) - content[s]).max() <= 1
                return done

            wait_until(faded_in, bool, what="every node faded into its picture", timeout=60, interval=0.01)
            assert mixed, "no node was seen between black and its picture during the crossfade"
            wait_until(lambda: page.cue_mark(1), lambda m: m.startswith("now"), what="the panel marking cue 2 current",
                       timeout=30)
            assert page.cue_mark(2) == "next"
            assert page.cue_go() == 2
            w, h = rig.local.output_size
            for s in SLOTS:
                grid = test_patterns.test_pattern("grid", (w, h), label=s)
                wait_until(lambda: rig.shown(s)[1], lambda img: img is not None and np.array_equal(img, grid),
                           what=f"{s} showing its labelled grid", timeout=60)

            # a node killed: the banner's alarm names it
            rig.kill_node("r3c3")
            wait_until(lambda: (driver.execute_script("return document.getElementById('health').dataset.level;"),
                                text_of(driver, "health")),
                       lambda lt: lt[0] == "alarm" and "r3c3 lost" in lt[1], what="the lost node on the banner",
                       timeout=60)

            # a viewer's GO is refused on the page, in one line, and changes nothing
            page.log_out()
            page.log_in(*VIEWER)
            wait_until(lambda: text_of(driver, "who"), lambda w: w == "vera (viewer)", what="who is logged in",
                       timeout=30)
            page.space_on_cues()
            refusal = wait_until(lambda: text_of(driver, "cue-error"), lambda t: "refused" in t,
                                 what="the viewer's GO refused on the page", timeout=60)
            assert "vera is a viewer" in refusal and "\n" not in refusal.strip(), refusal
            assert rig.call(lambda: rig.coord.cue_state().current) == 2
            wait_until(lambda: text_of(driver, "actions"), lambda t: "vera" in t and "refused" in t,
                       what="the refused GO in the action log, under the viewer's name", timeout=60)
        finally:
            driver.quit()
