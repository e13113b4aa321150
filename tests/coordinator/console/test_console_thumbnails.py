"""Thumbnails of what each projector shows, on the console: a real coordinator, real node
processes writing what they show to snapshot PNGs, and a headless Chromium (Debian's chromium and
chromedriver, through Selenium). Waits are generous failure guards, never measurements
(`bench/console.py` times the thumbnails' rate and their cost in late frames)."""
from __future__ import annotations

import asyncio
import json

import aiohttp
import numpy as np
import pytest

from bench.console import (ConsoleRig, all_shown, chromium, log_in, page_thumbnails, thumbnail_png,
                           visible, wait_for)
from coordinator.previews import WANTED_FOR_S
from coordinator.rig import Content
from node.image_files import decode_png, read_png
from node.preview import downscale
from waits import wait_until, wait_until_async

SLOTS = ["r0c0", "r0c1"]
OUTPUT = (320, 180)          # area-averaged by 2: 160 x 90 thumbnails
CONTENT = (160, 90)


def card(w: int, h: int) -> np.ndarray:
    """Colour ramps under a checkerboard: a blank, shifted or swapped thumbnail cannot pass for it."""
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack([xx * 255 // (w - 1), yy * 255 // (h - 1), 255 - xx * 255 // (w - 1)], -1)
    checker = ((xx // 8 + yy // 8) % 2).astype(bool)
    img[checker] //= 3
    return img.astype(np.uint8)


def snapshot(rig, slot: str) -> tuple[int, str, np.ndarray | None]:
    """(frame id, tag, image) of what ``slot``'s node last wrote as shown; (-1, "", None) before."""
    folder = rig.local.snapshot_dir
    try:
        meta = json.loads((folder / f"{slot}.json").read_text())
        return int(meta["frame_id"]), meta["tag"], read_png(folder / f"{slot}.png")
    except (OSError, ValueError, KeyError):
        return -1, "", None


@pytest.mark.slow
def test_each_thumbnail_matches_what_its_node_rendered(tmp_path, browser_ready):
    with ConsoleRig(tmp_path / "rig", SLOTS, output_size=OUTPUT, content_size=CONTENT, snapshots=True) as rig:
        rig.wait_live(timeout=240)
        rig.call(lambda: rig.coord.show(Content(card(*CONTENT), name="thumbnail card"), persist=False))
        shown = {}
        for slot in SLOTS:
            wait_for(lambda: snapshot(rig, slot)[1].startswith("show") and snapshot(rig, slot)[2] is not None, 120,
                     f"{slot}'s snapshot of the card")
            shown[slot] = snapshot(rig, slot)
        # the nodes' preview streams were open while the card went through them: no page, no request
        assert rig.call(lambda: dict(rig.coord.previews.asked)) == {}, "no page open: no node is asked"

        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            log_in(driver, rig.token)
            wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
            wait_for(lambda: all_shown(driver, SLOTS, "live"), 120, "every node live")
            for slot in SLOTS:
                frame, _, full = shown[slot]
                assert full.shape == (OUTPUT[1], OUTPUT[0], 3)
                wait_for(lambda: page_thumbnails(driver)[slot]["frame"] == str(frame), 60,
                         f"{slot}'s thumbnail of frame {frame}: the page shows {page_thumbnails(driver)[slot]}")
                thumb = page_thumbnails(driver)[slot]
                got = decode_png(thumbnail_png(thumb["src"]))
                want = downscale(full)
                assert got.shape == want.shape == (90, 160, 3)
                mad = np.abs(got.astype(float) - want).mean()
                assert mad < 1.0, f"{slot}: mean absolute difference {mad:.2f}"
                # not blank, and the card's structure (a correlation with what the node rendered)
                assert got.std() > 30 and np.corrcoef(got.ravel(), want.ravel())[0, 1] > 0.99
                assert thumb["text"].endswith(" s old") and float(thumb["age"]) < 5000
            # the two projectors show different parts of the card: each row has its own node's picture
            a, b = (decode_png(thumbnail_png(page_thumbnails(driver)[s]["src"])) for s in SLOTS)
            assert np.abs(a.astype(float) - b).mean() > 10

            # previews keep coming from every node while the page looks (their rate: bench/console.py)
            before = rig.call(lambda: dict(rig.coord.previews.received))
            wait_until(lambda: rig.call(lambda: dict(rig.coord.previews.received)),
                       lambda after: all(after[s] - before[s] >= 3 for s in SLOTS),
                       what=f"3 more previews from every node than {before}")

            # the page closed: no thumbnail is wanted any more, so no node is asked (that an unwanted
            # slot is asked no more: test_nodes_are_asked_for_previews_only_while_someone_looks)
            driver.get("about:blank")
            wait_until(lambda: rig.call(lambda: {s: rig.coord.previews.wanted(s) for s in SLOTS}),
                       lambda wanted: not any(wanted.values()), what="no thumbnail wanted once the page closed")
            logs = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
            assert not [e for e in logs if "Content Security Policy" in e.get("message", "")], logs
        finally:
            driver.quit()


@pytest.mark.slow
def test_nodes_are_asked_for_previews_only_while_someone_looks(tmp_path):
    """No page, no request: the coordinator asks a node only after its thumbnail was fetched, only
    that node, and stops a few seconds after the fetches stop. The route needs a session, says why
    it has nothing, and is never cached."""
    with ConsoleRig(tmp_path / "rig", SLOTS) as rig:
        rig.wait_live(timeout=240)
        asked = lambda: rig.call(lambda: dict(rig.coord.previews.asked))  # noqa: E731
        # no page, no request (r0c1 stays unasked through r0c0's looks below, a longer window)
        assert asked() == {} and rig.call(lambda: dict(rig.coord.previews.latest)) == {}
        base = rig.url.rstrip("/")

        async def session() -> tuple[aiohttp.ClientSession, dict]:
            s = aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar())
            r = await s.post(base + "/login", json={"token": rig.token}, headers={"Origin": base})
            return s, {"Cookie": f"shadowless_console={r.cookies['shadowless_console'].value}"}

        async def look(slot: str, asks: int) -> list[tuple[int, dict, bytes]]:
            """Fetch ``slot``'s thumbnail as a page does, a few times a second, until its node was asked
            ``asks`` times and one fetch brought a picture; every answer, in order."""
            s, cookie = await session()
            answers = []
            try:
                r = await s.get(base + "/api/thumbnail/" + slot)
                assert r.status == 401
                r = await s.get(base + "/api/thumbnail/%3Cimg%3E", headers=cookie)
                assert r.status == 404 and "no slot '<img>'" in (await r.json())["error"]

                async def fetch() -> tuple[list[int], int]:
                    r = await s.get(base + "/api/thumbnail/" + slot, headers=cookie)
                    answers.append((r.status, dict(r.headers), await r.read()))
                    return [a[0] for a in answers[-5:]], asked().get(slot, 0)

                await wait_until_async(fetch, lambda seen: seen[1] >= asks and any(a[0] == 200 for a in answers),
                                       what=f"{slot}'s node asked {asks} times and a thumbnail fetched "
                                            "(the last statuses, asks)", interval=0.3)
            finally:
                await s.close()
            return answers

        answers = asyncio.run(look("r0c0", 3))
        first = answers[0]
        assert first[0] == 404 and "no thumbnail of r0c0 yet" in json.loads(first[2])["error"]
        ok = [a for a in answers if a[0] == 200]
        assert ok, answers[:3]
        status, headers, body = ok[-1]
        assert headers["Content-Type"] == "image/png" and headers["Cache-Control"] == "no-store"
        assert int(headers["X-Frame-Id"]) >= 0 and float(headers["X-Age-Ms"]) < 3000
        assert headers["X-Output-Size"] == "64x36" and decode_png(body).shape == (36, 64, 3)
        n = asked()
        assert n.get("r0c0", 0) >= 3 and "r0c1" not in n, n
        # nobody looks any more: r0c0's thumbnail stops being wanted WANTED_FOR_S after the last fetch
        wait_until(lambda: rig.call(lambda: rig.coord.previews.wanted("r0c0")), lambda wanted: not wanted,
                   what=f"r0c0 no longer wanted, {WANTED_FOR_S} s after the last fetch")
        n = asked()
        # and its node is asked no more while r0c1's is asked three times, two of the coordinator's
        # ask periods apart
        asyncio.run(look("r0c1", 3))
        later = asked()
        assert later["r0c0"] == n["r0c0"] and later["r0c1"] >= 3, (n, later)
