"""`shadowless bench console_shots`: every screenshot of the console in docs/ photographed from a
running console, never edited by hand: ``console-layout.png`` (the layout over 25 overlapping
projectors), ``console-calibrate.png`` (table points picked on the camera view), ``console-cues.png``
(the cue panel during a show) and ``console.png`` (the whole page during a show).

The layout: a coordinator with its console runs in this process over a rig of N projectors (25 by default)
that all light one table, as a real rig does: each footprint covers most of the table, shifted,
scaled and turned a little, so every footprint overlaps every other. All but the last slot join
as protocol-level nodes (:mod:`shadowless.swarm`: they keep clocks and report, and render
nothing), so the page shows them live and the last one as never connected. Headless Chromium
(Debian's ``chromium`` and ``chromedriver``) logs in, selects one slot in the list beside the
layout, and photographs the health banner and the layout panel.

The others come from the page-only workflow in the virtual room (:mod:`bench.console_workflow`, the
steps the browser test takes): 2x2 projectors showing into a room in this process, the room's
camera, an operator logged in by name. The table is lit white, its marks clicked on the camera
view and their millimetres typed (photographed: the camera view with its marks and the points'
table), then calibrate, alignment, response, transport, an image shown and compensated, three cues
built and the second one fired with its crossfade (photographed: the cue panel, then the whole page).

Prints one JSON document: each picture's path and size, and what the page showed (the layout's
banner and labels; the workflow's steps with their seconds, the alignment's residuals, the
compensation's scores and the cue panel's line).
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import AsyncIterator

import numpy as np

from bench.console import browser_missing, chromium, log_in, page_thumbnails, text_of, visible, wait_for
from bench.machine import machine
from coordinator.app import CoordinatorApp
from coordinator.rig import HomographyPose, Rig
from shadowless.local import LocalRig
from shadowless.swarm import Swarm
from shadowless.swarm_config import SwarmConfig

OUTPUT = (1920, 1080)
CONTENT = (1600, 1000)
DOCS = Path("docs")
SHOTS = ("layout", "calibrate", "cues", "console")
#: the picture each shot writes, in the --docs folder
FILES = {"layout": "console-layout.png", "calibrate": "console-calibrate.png", "cues": "console-cues.png",
         "console": "console.png"}


def table_poses(n: int, *, seed: int = 7, output=OUTPUT, content=CONTENT) -> list[np.ndarray]:
    """``n`` homographies (content px -> projector px, (3, 3) float64) whose footprints each cover
    80-95 % of the table's width, centred within 4 % of its middle and turned up to 4 degrees: n
    projectors that all light one table."""
    import cv2

    rng = np.random.default_rng(seed)
    cw, ch = content
    w, h = output
    out = []
    for _ in range(n):
        s = rng.uniform(0.80, 0.95)
        a = math.radians(rng.uniform(-4, 4))
        cx, cy = cw / 2 + rng.uniform(-0.04, 0.04) * cw, ch / 2 + rng.uniform(-0.04, 0.04) * ch
        half = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * [s * cw / 2, s * ch / 2]
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        quad = (half @ rot.T + [cx, cy]).astype(np.float32)
        proj = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float32)
        out.append(cv2.getPerspectiveTransform(quad, proj).astype(np.float64))
    return out


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--projectors", type=int, default=25, help="projectors over the table (default 25)")
    p.add_argument("--select", default="", metavar="SLOT",
                   help="the slot selected in the picture (default: the eighth, blue)")
    p.add_argument("--docs", type=Path, default=DOCS, metavar="DIR",
                   help=f"where the pictures go (default {DOCS}/): " + ", ".join(FILES.values()))
    p.add_argument("--out", type=Path, default=None,
                   help="the layout's picture elsewhere (default DIR/console-layout.png)")
    p.add_argument("--only", default=",".join(SHOTS), metavar="SHOT,...",
                   help=f"which pictures (default all: {','.join(SHOTS)}; calibrate, cues and console come from one "
                        "run of the workflow in the virtual room, about two minutes)")
    p.add_argument("--width", type=int, default=960,
                   help="the browser window's width for the layout in pixels (default 960: the page in one column)")
    p.add_argument("--page-width", type=int, default=1400,
                   help="the browser window's width for the workflow's pictures (default 1400)")


def _shoot(url: str, token: str, select: str, out: Path, width: int, slots: list[str], workdir: Path) -> dict:
    """Log in, wait for the swarm's slots live, select ``select``, photograph; what the page showed."""
    from selenium.webdriver.common.by import By

    driver = chromium(workdir / "chromium-profile", size=(width, 1600))
    try:
        driver.get(url)
        log_in(driver, token)
        wait_for(lambda: visible(driver, "health"), 60, "the health banner")
        live = lambda: driver.execute_script(  # noqa: E731
            "return document.querySelectorAll('#slot-list li.state-live').length;")
        wait_for(lambda: live() >= len(slots) - 1, 120, f"{len(slots) - 1} slots live on the page")
        # the clocks settle about 20 s after the joins: the banner then says only what is wrong
        settled = lambda: not driver.find_elements(By.CSS_SELECTOR, '#health li[data-kind="clock"]')  # noqa: E731
        wait_for(settled, 90, "the clocks settled")
        driver.find_element(By.CSS_SELECTOR, f'#slot-list li[data-slot="{select}"]').click()
        wait_for(lambda: driver.find_elements(By.CSS_SELECTOR, f'#layout g.selected[data-slot="{select}"]'), 60,
                 f"{select} selected")
        # the banner above the layout panel, one picture of each element stacked on a white ground
        import cv2

        driver.execute_script("document.activeElement.blur();")
        parts = [cv2.imdecode(np.frombuffer(driver.find_element(By.ID, e).screenshot_as_png, np.uint8), cv2.IMREAD_COLOR)
                 for e in ("health", "layout-panel")]
        wide = max(p.shape[1] for p in parts)
        gap = np.full((12, wide, 3), 246, np.uint8)
        crop = np.vstack([parts[0][:, :wide], gap, parts[1][:, :wide]]) if parts[0].shape[1] == wide else np.vstack(
            [np.pad(parts[0], ((0, 0), (0, wide - parts[0].shape[1]), (0, 0)), constant_values=246), gap,
             np.pad(parts[1], ((0, 0), (0, wide - parts[1].shape[1]), (0, 0)), constant_values=246)])
        out.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(out), crop):
            raise OSError(f"cannot write {out}")
        labels = driver.execute_script(
            "return Array.from(document.querySelectorAll('#layout text.fp-name')).map(t => t.textContent);")
        return {"picture": str(out), "picture_px": [int(crop.shape[1]), int(crop.shape[0])],
                "banner": driver.find_element(By.ID, "health").text.splitlines(), "labels": labels,
                "faded": driver.execute_script("return document.querySelectorAll('#layout g.faded').length;")}
    finally:
        driver.quit()


@contextlib.asynccontextmanager
async def overlapping_rig(slots: list[str], workdir: Path) -> AsyncIterator[tuple[LocalRig, CoordinatorApp]]:
    """The layout's rig in ``workdir``: a coordinator with its console in this process, every slot
    posed by :func:`table_poses`, all but the last joined by protocol-level nodes. Yields the local
    rig (its token) and the running app. On leaving, the coordinator stops first and ends the
    swarm's sessions as closed, then the swarm: its nodes say no goodbye, so stopped first each
    would be logged as a node lost, which a normal shutdown is not."""
    local = LocalRig(slots, workdir, output_size=OUTPUT, content_size=CONTENT, mdns=False).create()
    rig = Rig(local.rig_dir)
    for s, H in zip(slots, table_poses(len(slots))):
        rig.update_slot(s, pose=HomographyPose(H))
    app = CoordinatorApp(Rig(local.rig_dir), local.token, listen=f"127.0.0.1:{local.port}", advertise=False,
                         console="127.0.0.1:0")
    await app.start()
    swarm = Swarm(SwarmConfig(slots=slots[:-1], token=local.token, coordinator=f"127.0.0.1:{local.port}",
                              fetch="manifest", join_concurrency=8))   # under the per-address budget
    try:
        await swarm.start()
        yield local, app
    finally:
        try:
            await app.stop(grace=1.0)
        finally:
            await swarm.stop()


async def _main(args: argparse.Namespace, workdir: Path) -> dict:
    n = args.projectors
    cols = math.ceil(math.sqrt(n))
    slots = [f"r{i // cols + 1}c{i % cols + 1}" for i in range(n)]
    select = args.select or slots[min(7, n - 1)]
    if select not in slots:
        raise SystemExit(f"--select {select!r}: not a slot of this rig ({slots[0]} … {slots[-1]})")
    async with overlapping_rig(slots, workdir) as (local, app):
        url = f"http://127.0.0.1:{app.console_port}/"
        t0 = time.monotonic()
        shot = await asyncio.to_thread(_shoot, url, local.token.decode(), select, args.out, args.width, slots, workdir)
        shot["seconds"] = round(time.monotonic() - t0, 1)
    return {"benchmark": "console_shots", "machine": machine(), "projectors": n, "selected": select,
            "never_connected": slots[-1], **shot}


def _say(msg: str) -> None:
    print(f"bench console_shots: {msg}", file=sys.stderr, flush=True)


def _workflow(args: argparse.Namespace, shots: list[str], workdir: Path) -> dict:
    """The page-only workflow in the virtual room (bench.console_workflow), photographed on the way."""
    import cv2

    from bench.compensation_room import demo_image
    from bench.console_workflow import (CONTENT as ROOM_CONTENT, MARKS_MM, SLOTS, RoomConsoleRig, Workflow,
                                        mark_pixels, small_room)
    from selenium.webdriver.support.ui import Select

    from coordinator.users import UserStore
    from sim.wire.service import RoomServerThread

    room = small_room(camera_scale=0.25)        # the camera view at 648x486: marks and table readable
    image = workdir / "astronaut.png"
    cv2.imwrite(str(image), cv2.cvtColor(demo_image(ROOM_CONTENT), cv2.COLOR_RGB2BGR))
    out: dict = {"projectors": SLOTS, "pictures": {}, "steps_s": {}}
    t0 = time.monotonic()

    def step(name: str) -> None:
        out["steps_s"][name] = round(time.monotonic() - t0, 1)
        _say(f"{name} ({out['steps_s'][name]} s)")

    with RoomServerThread(room) as server, \
            RoomConsoleRig(workdir / "room-rig", server.address, room.projector_size(SLOTS[0])) as rig:
        UserStore(rig.local.rig_dir).add("ola", "operator", "ola's password")
        driver = chromium(workdir / "chromium-workflow", size=(args.page_width, 1400))
        try:
            driver.get(rig.url)
            page = Workflow(rig, driver)
            page.log_in("ola", "ola's password")
            page.wait_live()
            step("every node live")
            # the table lit white (no pose is needed for a test pattern), its marks clicked and typed
            t = time.time()
            rig.call(lambda: rig.coord.show_test_pattern("white", None))
            page.camera_view(after=t + 0.5)
            wait_for(lambda: driver.execute_script(
                "const i = document.getElementById('camera-img'); return i.complete && i.naturalWidth > 0;"), 60,
                "the camera view")
            page.pick_points(mark_pixels(room), MARKS_MM)
            if "calibrate" in shots:
                path = args.docs / FILES["calibrate"]
                out["pictures"]["calibrate"] = {"picture": str(path),
                                                "picture_px": page.element_png(["pic-camera"], path)}
            step("table points picked")
            for kind, run in (("calibrate", page.calibrate_from_view), ("alignment", lambda: page.run_job("alignment")),
                              ("response", lambda: page.run_job("response")),
                              ("transport", lambda: page.run_job("transport"))):
                job = run()
                if job["state"] != "done":
                    raise RuntimeError(f"{kind} {job['state']}: {job['error']}")
                step(kind)
            out["alignment_rms_px"] = wait_for(lambda: page.alignment_rms() or None, 60, "the alignment table")
            page.show_image(image, image.name)
            job = page.run_job("compensate", ticks=("evaluate",))
            if job["state"] != "done":
                raise RuntimeError(f"compensate {job['state']}: {job['error']}")
            out["compensation_psnr_ssim"] = wait_for(lambda: page.compensation_scores() or None, 60,
                                                     "the compensation's scores")
            step("image shown and compensated")
            page.add_cue("Preset", "blackout")
            page.add_cue("Opening", "still", "content", fade_s=2.0)
            page.add_cue("Focus grid", "pattern", "grid")
            late = lambda: rig.call(lambda: {n.slot: n.frames_late for n in rig.coord.status().nodes})  # noqa: E731
            page.cue_go()
            before = late()
            page.cue_go()
            wait_for(lambda: page.cue_mark(1) == "now", 60, "the crossfade over, cue 2 current")
            after = late()
            out["late_frames_during_the_crossfade"] = {s: after[s] - before[s] for s in SLOTS}
            step("cues built, the second fired")
            # the thumbnails of what each projector shows, then the pictures
            page.scroll_to("nodes-panel")
            wait_for(lambda: all(v.get("src") for v in page_thumbnails(driver).values()), 60, "every thumbnail")
            out["cue_line"] = text_of(driver, "cue-now")
            if "cues" in shots:
                path = args.docs / FILES["cues"]
                out["pictures"]["cues"] = {"picture": str(path), "picture_px": page.element_png(["cues-panel"], path)}
            if "console" in shots:
                # the camera's view of the show, and the job form of a short job
                page.camera_view(after=time.time() + 0.5)
                wait_for(lambda: driver.execute_script(
                    "const i = document.getElementById('camera-img'); return i.complete && i.naturalWidth > 0;"), 60,
                    "the camera view")
                Select(driver.find_element("id", "job-kind")).select_by_value("alignment")
                path = args.docs / FILES["console"]
                out["pictures"]["console"] = {"picture": str(path), "picture_px": page.page_png(path, args.page_width)}
            out["banner"] = driver.find_element("id", "health").text.splitlines()
        finally:
            driver.quit()
    out["seconds"] = round(time.monotonic() - t0, 1)
    return out


def run(args: argparse.Namespace) -> int:
    missing = browser_missing()
    if missing:
        print(f"bench console_shots: {missing}", file=sys.stderr)
        return 1
    if not 2 <= args.projectors <= 100:
        print("bench console_shots: --projectors must be within 2..100", file=sys.stderr)
        return 1
    shots = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = [s for s in shots if s not in SHOTS]
    if unknown or not shots:
        print(f"bench console_shots: --only {args.only!r}: choose among {', '.join(SHOTS)}", file=sys.stderr)
        return 1
    if args.out is None:
        args.out = args.docs / FILES["layout"]
    doc: dict = {"benchmark": "console_shots", "machine": machine()}
    with tempfile.TemporaryDirectory(prefix="console-shots-") as tmp:
        if "layout" in shots:
            _say(f"the layout over {args.projectors} projectors")
            layout = asyncio.run(_main(args, Path(tmp)))
            doc.update({k: v for k, v in layout.items() if k not in ("benchmark", "machine")})
        if any(s in shots for s in ("calibrate", "cues", "console")):
            _say("the workflow in the virtual room (about two minutes)")
            doc["workflow"] = _workflow(args, shots, Path(tmp))
    print(json.dumps(doc, indent=2))
    return 0
