"""`shadowless bench console_shots`: the console's layout photographed from a running console, for
the docs (``docs/console-layout.png``), never edited by hand.

A coordinator with its console runs in this process over a rig of N projectors (25 by default)
that all light one table, as a real rig does: each footprint covers most of the table, shifted,
scaled and turned a little, so every footprint overlaps every other. All but the last slot join
as protocol-level nodes (:mod:`shadowless.swarm`: they keep clocks and report, and render
nothing), so the page shows them live and the last one as never connected. Headless Chromium
(Debian's ``chromium`` and ``chromedriver``) logs in, selects one slot in the list beside the
layout, and photographs the health banner and the layout panel. Prints one JSON document: the
picture's path and size, the slots, what the page showed.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.console import browser_missing, chromium, log_in, visible, wait_for
from bench.machine import machine
from coordinator.app import CoordinatorApp
from coordinator.rig import HomographyPose, Rig
from shadowless.local import LocalRig
from shadowless.swarm import Swarm
from shadowless.swarm_config import SwarmConfig

OUTPUT = (1920, 1080)
CONTENT = (1600, 1000)
DEFAULT_OUT = Path("docs/console-layout.png")


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
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"where the picture goes (default {DEFAULT_OUT})")
    p.add_argument("--width", type=int, default=960,
                   help="the browser window's width in pixels (default 960: the page in one column)")


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


async def _main(args: argparse.Namespace, workdir: Path) -> dict:
    n = args.projectors
    cols = math.ceil(math.sqrt(n))
    slots = [f"r{i // cols + 1}c{i % cols + 1}" for i in range(n)]
    select = args.select or slots[min(7, n - 1)]
    if select not in slots:
        raise SystemExit(f"--select {select!r}: not a slot of this rig ({slots[0]} … {slots[-1]})")
    local = LocalRig(slots, workdir, output_size=OUTPUT, content_size=CONTENT, mdns=False).create()
    rig = Rig(local.rig_dir)
    for s, H in zip(slots, table_poses(n)):
        rig.update_slot(s, pose=HomographyPose(H))
    app = CoordinatorApp(Rig(local.rig_dir), local.token, listen=f"127.0.0.1:{local.port}", advertise=False,
                         console="127.0.0.1:0")
    await app.start()
    swarm = Swarm(SwarmConfig(slots=slots[:-1], token=local.token, coordinator=f"127.0.0.1:{local.port}",
                              fetch="manifest", join_concurrency=8))   # under the per-address budget
    try:
        await swarm.start()
        url = f"http://127.0.0.1:{app.console_port}/"
        t0 = time.monotonic()
        shot = await asyncio.to_thread(_shoot, url, local.token.decode(), select, args.out, args.width, slots, workdir)
        shot["seconds"] = round(time.monotonic() - t0, 1)
    finally:
        await swarm.stop()      # the nodes first (their leaving is logged as lost), then the coordinator
        await app.stop(grace=1.0)
    return {"benchmark": "console_shots", "machine": machine(), "projectors": n, "selected": select,
            "never_connected": slots[-1], **shot}


def run(args: argparse.Namespace) -> int:
    missing = browser_missing()
    if missing:
        print(f"bench console_shots: {missing}", file=sys.stderr)
        return 1
    if not 2 <= args.projectors <= 100:
        print("bench console_shots: --projectors must be within 2..100", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="console-shots-") as tmp:
        doc = asyncio.run(_main(args, Path(tmp)))
    print(json.dumps(doc, indent=2))
    return 0
