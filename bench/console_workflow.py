"""The console's page-only workflow in the virtual room, step by step, for the browser test and the
docs' screenshots (``tests/coordinator/console/test_console_workflow.py``,
:mod:`bench.console_shots`).

:class:`RoomConsoleRig` is a coordinator with its console in this process whose node processes send
what they show to a virtual room (in a thread of this process) and whose camera is the room's.
:class:`Workflow` drives headless Chromium through what an operator does on the page alone: log in
by name, click the table's marks on the camera view and type their millimetres, run the jobs from
their forms, upload and show an image, compensate it, build a cue list and GO through it. Where the
truth matters it comes from the room (where its camera sees each table mark; what the camera should
see of an image), never from the coordinator's own results. Each step returns what it saw; the
caller checks it (the test) or photographs the page (the bench).
"""
from __future__ import annotations

import base64
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.console import ConsoleRig, text_of, visible, wait_for
from protos.spaces import content_to_table
from shadowless.local import LocalRig

#: 2x2 projectors of the reference room's 5x5 array, all aimed at the table's centre
SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]
#: the shared image over the 1200x600 mm table (6 mm per content px)
CONTENT = (200, 100)
TABLE_MM = (1200.0, 600.0)
#: the table marks the operator clicks (mm from the table's centre, +y away from the camera's top)
MARKS_MM = [(-520.0, 220.0), (520.0, 220.0), (520.0, -220.0), (-520.0, -220.0), (0.0, 0.0)]
#: the camera opened up for 4 of the room's 25 projectors (its automatic exposure is for all 25)
EXPOSURE = 5.0


def small_room(*, projector_scale: float = 0.1, camera_scale: float = 0.15, seed: int = 1):
    """The reference room at a small resolution (projectors 128x80, camera 389x292 at the default
    scales) with only :data:`SLOTS` powered and the camera exposed for them."""
    from sim.room import Room
    from sim.scene import reference_scene

    scene = reference_scene(projector_scale=projector_scale, camera_scale=camera_scale)
    scene = replace(scene, cameras=(replace(scene.cameras[0], exposure=EXPOSURE),))
    room = Room(scene, seed=seed)
    room.set_active(SLOTS)
    return room


class RoomConsoleRig(ConsoleRig):
    """A :class:`ConsoleRig` whose nodes (no pose yet) show into the room at ``room_address``, whose
    camera is the room's, and whose nodes keep snapshots of what they render."""

    def __init__(self, workdir: Path, room_address: str, output_size: tuple[int, int], *,
                 slots: list[str] = SLOTS, content_size: tuple[int, int] = CONTENT):
        camera = f"room://{room_address}"
        super().__init__(workdir, list(slots), posed=[], output_size=output_size, content_size=content_size,
                         cameras=[camera], snapshots=True)
        self.local = LocalRig(self.slots, Path(workdir), output_size=output_size, content_size=content_size,
                              mdns=False, snapshots=True, node_output=camera)

    def shown(self, slot: str) -> tuple[int, np.ndarray | None]:
        """(frame id, (H, W, 3) uint8 RGB) a node last rendered of a show, from its snapshot files
        ((0, None) before the first)."""
        import cv2

        snaps = self.local.snapshot_dir
        try:
            frame = json.loads((snaps / f"{slot}.json").read_text())["frame_id"]
            img = cv2.imread(str(snaps / f"{slot}.png"), cv2.IMREAD_UNCHANGED)
        except (OSError, ValueError, KeyError, TypeError):
            return 0, None
        return int(frame), None if img is None else cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)


# ---------------------------------------------------------------------- what the room says
def mark_pixels(room, marks_mm=MARKS_MM, camera: int = 0) -> np.ndarray:
    """(N, 2) float64: where the room's camera sees each table mark (camera px, (0, 0) the first
    pixel's centre), from the room's own geometry."""
    H = room.truth.table_to_camera_homography(camera)
    xy1 = np.column_stack([np.asarray(marks_mm, np.float64), np.ones(len(marks_mm))])
    uvw = xy1 @ H.T
    return uvw[:, :2] / uvw[:, 2:]


def expected_view(room, image: np.ndarray, camera_size: tuple[int, int], *, content_size=CONTENT,
                  table_mm=TABLE_MM, camera: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """What the room's camera should see of ``image`` ((h, w, 3) uint8 content) shown on the table:
    ``(grey (H, W) float64, on_table (H, W) bool)`` at ``camera_size`` (the view's own size, which
    may be the capture scaled down), from the room's table-to-camera geometry."""
    import cv2

    W, H = camera_size
    cam_w, cam_h = room.camera_size(camera)
    scale = np.diag([W / cam_w, H / cam_h, 1.0])
    shift = lambda d: np.array([[1, 0, d], [0, 1, d], [0, 0, 1.0]])   # noqa: E731 - pixel centres
    h = shift(-0.5) @ scale @ shift(0.5) @ room.truth.table_to_camera_homography(camera) @ content_to_table(
        content_size, table_mm)
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float64)
    seen = cv2.warpPerspective(grey, h, (W, H), flags=cv2.INTER_LINEAR)
    inside = cv2.warpPerspective(np.ones_like(grey), h, (W, H), flags=cv2.INTER_NEAREST) > 0.5
    inside = cv2.erode(inside.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return seen, inside


def correlation(view: np.ndarray, expected: np.ndarray, inside: np.ndarray) -> float:
    """Pearson correlation of a camera view ((H, W, 3) uint8) with the expected grey picture over
    ``inside`` (0 for a flat view)."""
    import cv2

    a = cv2.cvtColor(view, cv2.COLOR_RGB2GRAY).astype(np.float64)[inside]
    b = expected[inside]
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


# ---------------------------------------------------------------------- the page
class Workflow:
    """An operator's steps on the console's page (``driver``: a Selenium Chromium) against ``rig``."""

    def __init__(self, rig: RoomConsoleRig, driver, *, job_timeout: float = 600.0):
        self.rig, self.driver = rig, driver
        self.job_timeout = job_timeout

    # -------------------------------------------------------------- helpers
    def by_id(self, element_id: str):
        return self.driver.find_element("id", element_id)

    def js(self, script: str, *args) -> Any:
        return self.driver.execute_script(script, *args)

    def coord(self, fn) -> Any:
        return self.rig.call(fn)

    def log_in(self, name: str, password: str) -> None:
        """Log in by name and password and wait for the control page."""
        wait_for(lambda: visible(self.driver, "login-view"), 60, "the login form")
        for field, text in (("login-name", name), ("token", password)):
            e = self.by_id(field)
            e.clear()
            e.send_keys(text)
        self.by_id("login-button").click()
        wait_for(lambda: visible(self.driver, "main-view"), 60,
                 f"the console after {name}'s login; the form says {text_of(self.driver, 'login-error')!r}")

    def log_out(self) -> None:
        self.by_id("logout").click()
        wait_for(lambda: visible(self.driver, "login-view"), 60, "the login form after logging out")

    def wait_live(self, timeout: float = 240.0) -> None:
        from bench.console import all_shown, page_states

        wait_for(lambda: all_shown(self.driver, self.rig.slots, "live"), timeout,
                 f"every node live on the page: {page_states(self.driver)}")

    def scroll_to(self, element_id: str) -> None:
        self.js("document.getElementById(arguments[0]).scrollIntoView({block: 'center'});", element_id)

    # -------------------------------------------------------------- the camera view
    def camera_view(self, after: float = 0.0, timeout: float = 60.0) -> np.ndarray:
        """The camera view as the page shows it ((H, W, 3) uint8 RGB), a capture the coordinator
        made after the wall time ``after`` (the page's Refresh button, again until one is)."""
        import cv2

        self.scroll_to("pic-camera")
        deadline = time.monotonic() + timeout
        while True:
            wait_for(lambda: not self.by_id("camera-refresh").get_attribute("disabled"), 60, "the camera's Refresh")
            self.by_id("camera-refresh").click()
            got = self.driver.execute_async_script(
                "const done = arguments[arguments.length - 1];"
                "fetch('/api/camera.png', {credentials: 'same-origin'}).then(async r => {"
                " const b = new Uint8Array(await r.arrayBuffer()); let s = '';"
                " for (let i = 0; i < b.length; i += 8192)"
                "  s += String.fromCharCode.apply(null, b.subarray(i, i + 8192));"
                " done([r.status, Number(r.headers.get('X-Captured-At') || 0), btoa(s)]); })"
                ".catch(e => done([0, 0, String(e)]));")
            status, at, data = got
            if status == 200 and at >= after:
                img = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
                return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
            if time.monotonic() > deadline:
                raise TimeoutError(f"no camera view captured after {after:.1f} within {timeout:.0f} s "
                                   f"(last answer {status})")
            time.sleep(0.5)

    def pick_points(self, pixels: np.ndarray, marks_mm=MARKS_MM) -> list[tuple[float, float]]:
        """Tick *pick points*, click each camera pixel on the camera view, type its mark's mm beside
        it; the (u, v) the page's table says for each point."""
        from selenium.webdriver.common.actions.action_builder import ActionBuilder

        d = self.driver
        self.scroll_to("pic-camera")
        wait_for(lambda: self.js("const i = document.getElementById('camera-img');"
                                 "return !i.hidden && i.complete && i.naturalWidth > 0;"), 120, "the camera view")
        capture = wait_for(self._capture_size, 60, "the capture's size")
        if not self.by_id("calib-pick").is_selected():
            self.by_id("calib-pick").click()
        for u, v in pixels:
            left, top, width, height = self.js(
                "const r = document.getElementById('camera-img').getBoundingClientRect();"
                "return [r.left, r.top, r.width, r.height];")
            x = left + (u + 0.5) / capture[0] * width
            y = top + (v + 0.5) / capture[1] * height
            before = len(d.find_elements("css selector", "#calib-points tbody tr"))
            actions = ActionBuilder(d)
            actions.pointer_action.move_to_location(int(round(x)), int(round(y))).click()
            actions.perform()
            wait_for(lambda: len(d.find_elements("css selector", "#calib-points tbody tr")) == before + 1, 30,
                     "the clicked point in the table")
        rows = d.find_elements("css selector", "#calib-points tbody tr")
        for row, (x_mm, y_mm) in zip(rows, marks_mm):
            for cls, value in (("calib-mm-x", x_mm), ("calib-mm-y", y_mm)):
                field = row.find_element("css selector", f"input.{cls}")
                field.clear()
                field.send_keys(f"{value:g}")
        return [tuple(p) for p in self.js("return Array.from(document.querySelectorAll('#calib-points tbody tr'))"
                                          ".map(tr => [Number(tr.dataset.u), Number(tr.dataset.v)]);")]

    def _capture_size(self) -> list[int] | None:
        """The capture's (width, height) as GET /api/pictures says it (the page uses the same)."""
        got = self.driver.execute_async_script(
            "const done = arguments[arguments.length - 1];"
            "fetch('/api/pictures', {credentials: 'same-origin'}).then(r => r.json())"
            ".then(d => done(d && d.camera && d.camera.size || null)).catch(() => done(null));")
        return list(got) if got else None

    # -------------------------------------------------------------- jobs
    def job(self) -> dict | None:
        return self.coord(lambda: self.rig.coord.job_snapshot())

    def wait_job(self, kind: str, started_after: float) -> dict:
        """Wait for the job ``kind`` started after ``started_after`` (wall) to end; its snapshot."""
        def ended():
            j = self.job()
            return j if j and j["kind"] == kind and j["started"] >= started_after and j["state"] != "running" else None

        job = wait_for(ended, self.job_timeout,
                       f"the {kind} job's end; the page says {text_of(self.driver, 'job-line')!r}", poll=0.2)
        wait_for(lambda: text_of(self.driver, "job-line").startswith(f"{kind} {job['state']}"), 60,
                 f"the {kind} job's end on the page")
        return job

    def calibrate_from_view(self) -> dict:
        """Start calibrate with the points in the camera view's table (its Calibrate button)."""
        t = time.time() - 1.0
        self.scroll_to("calib-start")
        self.by_id("calib-start").click()
        return self.wait_job("calibrate", t)

    def run_job(self, kind: str, ticks: tuple[str, ...] = ()) -> dict:
        """Choose ``kind`` in the job form, tick the checkbox options ``ticks``, Start, wait for its end."""
        from selenium.webdriver.support.ui import Select

        self.scroll_to("jobs-panel")
        wait_for(lambda: self.js("return Array.from(document.getElementById('job-kind').options)"
                                 ".some(o => o.value === arguments[0]);", kind), 60, f"{kind} among the jobs")
        Select(self.by_id("job-kind")).select_by_value(kind)
        wait_for(lambda: self.driver.find_elements("css selector", "#job-fields [data-option]"), 60, f"the {kind} form")
        for name in ticks:
            box = self.by_id(f"job-opt-{name}")
            if not box.is_selected():
                box.click()
        wait_for(self.by_id("job-start").is_enabled, 60, "the job form's Start enabled")
        t = time.time() - 1.0
        self.by_id("job-start").click()
        return self.wait_job(kind, t)

    def alignment_rms(self) -> dict[str, float]:
        """Each projector's alignment residual (rms px) as the Pictures panel's table lists it."""
        rows = self.js("return Array.from(document.querySelectorAll('#pic-alignment-slots tbody tr'))"
                       ".map(tr => Array.from(tr.cells).map(td => td.textContent));")
        out = {}
        for cells in rows:
            try:
                out[cells[0]] = float(cells[1])
            except (IndexError, ValueError):
                pass
        return out

    def compensation_scores(self) -> dict[str, tuple[float, float]]:
        """{"none" | "baseline" | "ours": (PSNR dB, SSIM)} as the Pictures panel's scores list them."""
        rows = self.js("return Array.from(document.querySelectorAll('#pic-compensation-scores tbody tr'))"
                       ".map(tr => [tr.dataset.result]"
                       ".concat(Array.from(tr.cells).slice(1).map(td => td.textContent)));")
        out = {}
        for key, psnr, ssim in rows:
            try:
                out[key] = (float(psnr), float(ssim))
            except ValueError:
                pass
        return out

    # -------------------------------------------------------------- content
    def show_image(self, path: Path, name: str) -> None:
        """Upload ``path`` in *Show an image*, kept as the rig's content; wait until the page says it
        is shown."""
        self.scroll_to("content-panel")
        self.by_id("image").send_keys(str(Path(path).resolve()))
        if not self.by_id("persist").is_selected():
            self.by_id("persist").click()
        self.by_id("show-button").click()
        wait_for(lambda: name in text_of(self.driver, "showing"), 120,
                 f"{name} shown; the form says {text_of(self.driver, 'show-error')!r}")

    # -------------------------------------------------------------- cues
    def add_cue(self, name: str, kind: str, target: str = "", fade_s: float = 0.0) -> None:
        """Fill the cue form and add the cue; wait until the panel lists it."""
        from selenium.webdriver.support.ui import Select

        self.scroll_to("cues-panel")
        wait_for(self.by_id("cue-save").is_enabled, 30, "the cue form's button enabled")
        self.by_id("cue-name").send_keys(name)
        Select(self.by_id("cue-kind")).select_by_value(kind)
        if target:
            self.by_id("cue-target").clear()
            self.by_id("cue-target").send_keys(target)
        fade = self.by_id("cue-fade")
        fade.clear()
        fade.send_keys(f"{fade_s:g}")
        self.by_id("cue-save").click()
        wait_for(lambda: name in text_of(self.driver, "cues"), 30,
                 f"cue {name!r} listed; the form says {text_of(self.driver, 'cue-form-error')!r}")

    def cue_go(self) -> int:
        """GO on the page; the index of the cue the core then holds as current."""
        before = self.coord(lambda: self.rig.coord.cue_state().current)
        want = 0 if before is None else before + 1
        wait_for(self.by_id("cue-go").is_enabled, 30, "GO enabled")
        self.by_id("cue-go").click()
        wait_for(lambda: self.coord(lambda: self.rig.coord.cue_state().current) == want, 60, f"GO fired cue {want + 1}")
        return want

    def cue_mark(self, index: int) -> str:
        """What the cue panel's first column says of cue ``index`` (0-based): "now", "next" or ""."""
        return self.js("const td = document.querySelector(`#cues tr[data-index='${arguments[0]}'] .cue-mark`);"
                       "return td ? td.textContent : '';", index)

    def space_on_cues(self) -> None:
        """The space bar with the cue panel focused (GO without its button)."""
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys

        self.scroll_to("cues-panel")
        self.js("document.getElementById('cues-panel').focus();")
        ActionChains(self.driver).send_keys(Keys.SPACE).perform()

    # -------------------------------------------------------------- pictures of the page
    def element_png(self, element_ids: list[str], out: Path, pad: int = 12) -> tuple[int, int]:
        """Photograph these elements and stack them (a light grey gap between) into ``out``; its size."""
        import cv2

        self.js("document.activeElement && document.activeElement.blur();")
        parts = []
        for e in element_ids:
            self.scroll_to(e)
            parts.append(cv2.imdecode(np.frombuffer(self.by_id(e).screenshot_as_png, np.uint8), cv2.IMREAD_COLOR))
        wide = max(p.shape[1] for p in parts)
        rows = []
        for k, p in enumerate(parts):
            if k:
                rows.append(np.full((pad, wide, 3), 246, np.uint8))
            rows.append(np.pad(p, ((0, 0), (0, wide - p.shape[1]), (0, 0)), constant_values=246))
        img = np.vstack(rows)
        out.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(out), img):
            raise OSError(f"cannot write {out}")
        return int(img.shape[1]), int(img.shape[0])

    def page_png(self, out: Path, width: int) -> tuple[int, int]:
        """The whole page (the window made as tall as the page) into ``out``; its size."""
        import cv2

        self.js("document.activeElement && document.activeElement.blur(); window.scrollTo(0, 0);")
        height = int(self.js("return Math.ceil(document.documentElement.scrollHeight);"))
        self.driver.set_window_size(width, min(height + 140, 12000))
        time.sleep(0.3)          # the layout after the resize (no event says it is done)
        png = self.driver.get_screenshot_as_png()
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        out.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(out), img):
            raise OSError(f"cannot write {out}")
        return int(img.shape[1]), int(img.shape[0])
