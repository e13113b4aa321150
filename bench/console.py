"""`shadowless bench console`: the operator console in a real browser against a real rig.

A coordinator with its console runs in a thread of this process, N offscreen node processes
join it over loopback, and a headless Chromium (Debian's ``chromium`` and ``chromedriver``,
driven by Selenium) opens the page. Measured: the page's load time, the time from the login
to every node shown live, how long a change takes to show on the page (a slot's gain set on
the coordinator; a node killed until it is shown lost), the coordinator's CPU time per
second with the page open and closed, the swap skew (p99) and late frames of sequences played with
the page closed, open, and open with the thumbnails of what each projector shows (the node rows
scrolled off screen: no node is asked; on screen: about one per second per node), and how many
thumbnails arrive per second per node. A screenshot of the page is saved. Cues: the time from GO to
the cue's first swap on every node, and the skew across the nodes of a crossfade's steps
(:mod:`bench.console_cues`).

:class:`ConsoleRig` and the page helpers are shared with the browser tests.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import random
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench.console_cues import cue_figures
from bench.machine import machine
from bench.workdir import run_dir
from coordinator.api import NodeState, PlayResult, PlaySettings
from coordinator.previews import WANTED_FOR_S
from coordinator.rig import HomographyPose, Rig
from coordinator.app import CoordinatorApp
from coordinator.server import Coordinator
from shadowless.local import LocalRig, grid_names

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


def browser_missing() -> str | None:
    """Why no headless browser can run here (None: it can)."""
    for path, package in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not os.access(path, os.X_OK):
            return f"{path} not found: install Debian's {package} (apt-get install chromium chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed in this environment"
    return None


def grid_pose(i: int, n: int, output: tuple[int, int], content: tuple[int, int]) -> np.ndarray:
    """A homography for projector ``i`` of ``n`` tiling the content in a grid with some overlap
    (content px -> projector px)."""
    cols = max(1, math.ceil(math.sqrt(n)))
    rows = math.ceil(n / cols)
    r, c = divmod(i, cols)
    cw, ch = content
    tw, th = cw / cols, ch / rows
    x0, y0 = c * tw - 0.1 * tw, r * th - 0.1 * th
    sx, sy = output[0] / (1.2 * tw), output[1] / (1.2 * th)
    return np.array([[sx, 0.0, -sx * x0], [0.0, sy, -sy * y0], [0.0, 0.0, 1.0]])


class ConsoleRig:
    """A coordinator with its console in a thread of this process, plus node processes.

    Use as a context manager; on exit the nodes are stopped (SIGTERM), then the coordinator.
    ``posed`` slots get a grid homography (the others are drawn beside the layout).
    """

    def __init__(self, workdir: Path, slots: list[str], *, posed: list[str] | None = None,
                 output_size=(64, 36), content_size=(160, 90), cameras: list[str] | None = None,
                 snapshots: bool = False):
        self.slots = list(slots)
        self.cameras = cameras
        self.local = LocalRig(self.slots, Path(workdir), output_size=output_size, content_size=content_size, mdns=False,
                              snapshots=snapshots)
        self.posed = self.slots if posed is None else list(posed)
        self.app: CoordinatorApp | None = None
        self.coord: Coordinator | None = None       # the app's core
        self.url = ""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None

    @property
    def token(self) -> str:
        return self.local.token.decode()

    def __enter__(self) -> "ConsoleRig":
        try:
            self.local.create()
            rig = Rig(self.local.rig_dir)
            for i, s in enumerate(self.slots):
                if s in self.posed:
                    rig.update_slot(s, pose=HomographyPose(grid_pose(i, len(self.slots), self.local.output_size,
                                                                     self.local.content_size)))
            self._thread = threading.Thread(target=self._run, name="console-coordinator", daemon=True)
            self._thread.start()
            if not self._ready.wait(60) or self._error is not None:
                raise RuntimeError(f"the coordinator did not start: {self._error!r}")
            for s in self.slots:
                self.local.start_node(s)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _run(self) -> None:
        async def main():
            self._loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()
            try:
                self.app = CoordinatorApp(Rig(self.local.rig_dir), self.local.token,
                                          listen=f"127.0.0.1:{self.local.port}", advertise=False,
                                          console="127.0.0.1:0", cameras=self.cameras)
                self.coord = self.app.coordinator
                await self.app.start()
                self.url = f"http://127.0.0.1:{self.app.console_port}/"
            except BaseException as exc:
                self._error = exc
                self._ready.set()
                if self.app is not None:
                    await self.app.stop()
                return
            self._ready.set()
            try:
                await self._stop.wait()
            finally:
                await self.app.stop(grace=1.0)

        asyncio.run(main())

    def call(self, fn: Callable[[], Any], timeout: float = 60.0) -> Any:
        """Run ``fn()`` (a plain function or one returning a coroutine) in the coordinator's loop."""
        async def wrapper():
            r = fn()
            return await r if asyncio.iscoroutine(r) else r
        return asyncio.run_coroutine_threadsafe(wrapper(), self._loop).result(timeout)

    def states(self) -> dict[str, str]:
        return self.call(lambda: {n.slot: n.state.value for n in self.coord.status().nodes})

    def wait_live(self, slots: list[str] | None = None, timeout: float = 180.0) -> None:
        want = set(self.slots if slots is None else slots)
        deadline = time.monotonic() + timeout
        while True:
            states = self.states()
            if all(states.get(s) == NodeState.LIVE.value for s in want):
                return
            for s in want:
                p = self.local.nodes.get(s)
                if p is not None and p.poll() is not None:
                    raise RuntimeError(f"node {s} exited with {p.returncode}:\n{self.local.log('node-' + s)[-3000:]}")
            if time.monotonic() > deadline:
                raise TimeoutError(f"nodes not live after {timeout:.0f} s: {states}")
            time.sleep(0.2)

    def kill_node(self, slot: str) -> None:
        """SIGKILL the node process of ``slot`` (one this rig started, by its pid)."""
        proc = self.local.nodes[slot]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)

    def close(self) -> None:
        self.local.close()
        if self._thread is not None:
            if self._loop is not None and self._stop is not None:
                try:
                    self._loop.call_soon_threadsafe(self._stop.set)
                except RuntimeError:
                    pass       # the loop already ended
            self._thread.join(60)
            self._thread = None


# ---------------------------------------------------------------------- the browser
def chromium(user_data_dir: Path, *, size=(1400, 2000)):
    """A headless Chromium driven through Debian's chromedriver."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", f"--user-data-dir={user_data_dir}",
              f"--window-size={size[0]},{size[1]}", "--disable-dev-shm-usage", "--no-first-run",
              "--disable-extensions", "--disable-background-networking"):
        opts.add_argument(a)
    # Chromium's scratch files (with --disable-dev-shm-usage its shared memory is files in TMPDIR,
    # and a few outlived quit()) go into a directory of their own, removed by quit(); its path is
    # short because Chromium's sockets live there too (a socket's path has at most 107 bytes)
    scratch = tempfile.mkdtemp(prefix="chromium-")
    service = Service(CHROMEDRIVER, log_output=str(Path(user_data_dir).with_suffix(".chromedriver.log")),
                      env={**os.environ, "TMPDIR": scratch})
    try:
        driver = webdriver.Chrome(service=service, options=opts)
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    quit_driver = driver.quit

    def quit_and_clean() -> None:
        try:
            quit_driver()
        finally:
            shutil.rmtree(scratch, ignore_errors=True)

    driver.quit = quit_and_clean
    return driver


def wait_for(fn: Callable[[], Any], timeout: float, what: str, poll: float = 0.02) -> Any:
    """Poll ``fn()`` until it is truthy; TimeoutError naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        v = fn()
        if v:
            return v
        if time.monotonic() > deadline:
            raise TimeoutError(f"not seen on the page within {timeout:.0f} s: {what}")
        time.sleep(poll)


def page_states(driver) -> dict[str, str]:
    """Each slot's state as the node table shows it."""
    return dict(driver.execute_script(
        "return Array.from(document.querySelectorAll('#nodes tbody tr'))"
        ".map(tr => [tr.getAttribute('data-slot'), tr.querySelector('td.state').textContent]);"))


def page_gains(driver) -> dict[str, str]:
    return dict(driver.execute_script(
        "return Array.from(document.querySelectorAll('#nodes tbody tr'))"
        ".map(tr => [tr.getAttribute('data-slot'), tr.querySelector('input.gain').value]);"))


def page_thumbnails(driver) -> dict[str, dict[str, Any]]:
    """Each node row's thumbnail as the page shows it: ``src`` (a data: URL, "" before the first),
    ``frame`` (the frame id it shows) and ``age`` (its age in ms when fetched, text as on the page)."""
    return dict(driver.execute_script(
        "return Array.from(document.querySelectorAll('#nodes tbody tr')).map(tr => {"
        " const img = tr.querySelector('img.thumb-img');"
        " return [tr.getAttribute('data-slot'), {src: img && !img.hidden ? img.src : '',"
        " frame: img ? (img.dataset.frame || '') : '', age: img ? (img.dataset.age || '') : '',"
        " text: (tr.querySelector('.thumb-age') || {}).textContent || ''}]; });"))


def thumbnail_png(src: str) -> bytes:
    """The PNG bytes of a thumbnail's data: URL."""
    import base64

    head, _, data = src.partition(",")
    if not head.startswith("data:image/png;base64"):
        raise ValueError(f"not a PNG data URL: {src[:40]!r}")
    return base64.b64decode(data)


def visible(driver, element_id: str) -> bool:
    return bool(driver.execute_script(f"const e = document.getElementById('{element_id}'); "
                                      "return !!e && !e.hidden && e.offsetParent !== null;"))


def text_of(driver, element_id: str) -> str:
    return driver.execute_script(f"return document.getElementById('{element_id}').textContent;")


def click(driver, element_id: str, timeout: float = 60.0) -> None:
    """Click the element with ``element_id`` once nothing covers it: a page laid out again between
    Selenium's scroll and its click (a banner or a table growing above it, slow on a loaded host)
    makes the click land on another element, which Chromium refuses rather than clicks; tried again
    until ``timeout``."""
    from selenium.common.exceptions import ElementClickInterceptedException, StaleElementReferenceException

    def attempt() -> bool:
        try:
            driver.find_element("id", element_id).click()
            return True
        except (ElementClickInterceptedException, StaleElementReferenceException):
            return False

    wait_for(attempt, timeout, f"#{element_id} clickable (not covered by another element)", poll=0.1)


def log_in(driver, token: str, timeout: float = 60.0) -> None:
    """Type the token into the login form and submit it."""
    from selenium.webdriver.common.by import By

    wait_for(lambda: visible(driver, "login-view"), timeout, "the login form")
    field = driver.find_element(By.ID, "token")
    field.clear()
    field.send_keys(token)
    driver.find_element(By.ID, "login-button").click()


def all_shown(driver, slots: list[str], state: str) -> bool:
    shown = page_states(driver)
    return all(shown.get(s) == state for s in slots)


# ---------------------------------------------------------------------- the benchmark
def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=int, default=4, help="node processes (default 4)")
    p.add_argument("--gain-changes", type=int, default=20, help="gain changes timed until shown (default 20)")
    p.add_argument("--kills", type=int, default=2, help="nodes killed, timed until shown lost (default 2)")
    p.add_argument("--cpu-seconds", type=float, default=10.0, help="each CPU measurement's length (default 10)")
    p.add_argument("--thumbnail-seconds", type=float, default=10.0,
                   help="length of each sequence played with the page closed, open, and open with thumbnails "
                        "(default 10)")
    p.add_argument("--warmup", type=float, default=25.0,
                   help="seconds for the nodes' clock estimates to settle before measuring CPU (default 25)")
    p.add_argument("--screenshot", metavar="PNG", help="where to save the page's screenshot (default: console.png "
                                                       "in the run's directory, kept only with --keep)")
    p.add_argument("--keep", metavar="DIR", help="keep the rig directory and logs here")
    p.add_argument("--cue-rounds", type=int, default=10,
                   help="cuts and crossfades each fired with GO for go_to_swap_ms_p99 and crossfade_skew_ms_p99 "
                        "(default 10; 0: none)")
    p.add_argument("--cue-fade", type=float, default=1.0, metavar="S", help="the crossfades' length (default 1 s)")


def _p99(values: list[float]) -> float | None:
    return round(float(np.percentile(values, 99)), 1) if values else None


def _cpu_ms_per_s(seconds: float) -> float:
    """This process's CPU time per wall second over ``seconds`` (the coordinator's thread, its gRPC
    and worker threads; this thread only sleeps meanwhile)."""
    c0, t0 = time.process_time(), time.monotonic()
    time.sleep(seconds)
    return round(1e3 * (time.process_time() - c0) / (time.monotonic() - t0), 2)


def _play(rig: ConsoleRig, seconds: float) -> PlayResult:
    """A 30 fps counter sequence of ``seconds`` played to its end on every node: its late frames and
    per-frame swap skews."""
    settings = PlaySettings(fps=30, pattern="counter", frames=max(1, round(30 * seconds)), wait=True)
    return rig.call(lambda: rig.coord.play_sequence(None, settings), timeout=seconds + 120)


def rows_on_screen(driver, on: bool) -> None:
    """Scroll the node table into view, or out of it (a tall spacer at the page's end makes room):
    the page fetches thumbnails only for the rows on screen."""
    driver.execute_script(
        "let s = document.getElementById('bench-spacer');"
        "if (!s) { s = document.createElement('div'); s.id = 'bench-spacer'; s.style.height = '6000px';"
        " document.body.appendChild(s); }"
        "if (arguments[0]) { window.scrollTo(0, 0); document.getElementById('nodes').scrollIntoView(); }"
        "else { window.scrollTo(0, document.body.scrollHeight); }", on)


def open_page(rig: ConsoleRig, driver, slots: list[str]) -> None:
    """Open the console again (the session cookie logs it in) and wait for every node shown live."""
    driver.get(rig.url)
    wait_for(lambda: all_shown(driver, slots, "live"), 120, f"every node live again: {slots}")


def play_figures(rig: ConsoleRig, driver, slots: list[str], seconds: float, rounds: int = 2) -> dict:
    """Sequences played in interleaved rounds of three kinds: the page closed (the browser on
    about:blank: no event stream, no request), the page open with the node rows scrolled off screen
    (the page fetches no thumbnail: no node is asked) and open with them on screen (each row
    refreshed about once a second). Per kind: the late frames and the swap skew's p99 over every
    frame of its rounds; and the thumbnails that arrived per second per node while the rows were on
    screen. Interleaving spreads the machine's other load over the three alike."""
    def count(name: str, only: list[str] | None = None) -> int:
        per_slot = rig.call(lambda: dict(getattr(rig.coord.previews, name)))
        return sum(n for s, n in per_slot.items() if only is None or s in only)

    kinds = ("closed", "open", "thumbnails")
    late = dict.fromkeys(kinds, 0)
    skews: dict[str, list[float]] = {k: [] for k in kinds}
    asked_off, got, spent, shown = 0, 0, 0.0, slots

    def played(kind: str) -> None:
        r = _play(rig, seconds)
        late[kind] += r.frames_late
        skews[kind] += [v for v in r.skews_ms if math.isfinite(v)]

    for _ in range(rounds):
        driver.get("about:blank")
        time.sleep(WANTED_FOR_S + 1.0)
        played("closed")
        open_page(rig, driver, slots)
        rows_on_screen(driver, False)
        time.sleep(WANTED_FOR_S + 1.0)      # the last thumbnail fetched is no longer wanted
        asked = count("asked")
        played("open")
        asked_off += count("asked") - asked
        rows_on_screen(driver, True)
        shown = [s for s in driver.execute_script(
            "return Array.from(document.querySelectorAll('#nodes tbody tr')).filter(tr => {"
            " const r = tr.getBoundingClientRect(); return r.bottom > 0 && r.top < window.innerHeight; })"
            ".map(tr => tr.getAttribute('data-slot'));") if s in slots]
        wait_for(lambda: all(page_thumbnails(driver).get(s, {}).get("src") for s in shown), 60,
                 f"the thumbnails of the rows on screen: {shown}")
        received, t = count("received", shown), time.monotonic()
        played("thumbnails")
        spent += time.monotonic() - t
        got += count("received", shown) - received
    driver.execute_script("const s = document.getElementById('bench-spacer'); if (s) s.remove(); window.scrollTo(0, 0);")
    p99 = {k: _p99(v) for k, v in skews.items()}
    ratio = (lambda a, b: round(a / b, 3) if a is not None and b else None)
    return {"thumbnails_per_s_per_node": round(got / spent / max(1, len(shown)), 2),
            "thumbnail_rows_on_screen": len(shown),
            "late_frames_page_closed": late["closed"], "late_frames_without_thumbnails": late["open"],
            "late_frames_with_thumbnails": late["thumbnails"],
            "previews_asked_rows_off_screen": asked_off,
            "swap_skew_ms_p99_page_closed": p99["closed"], "swap_skew_ms_p99_page_open": p99["open"],
            "swap_skew_ms_p99_with_thumbnails": p99["thumbnails"],
            "swap_skew_p99_open_over_closed": ratio(p99["open"], p99["closed"]),
            "swap_skew_p99_thumbnails_over_closed": ratio(p99["thumbnails"], p99["closed"]),
            "played_sequences": {"rounds": rounds, "seconds_each": seconds, "fps": 30,
                                 "frames_per_kind": {k: len(v) for k, v in skews.items()}}}


def measure(args: argparse.Namespace, workdir: Path, screenshot: Path) -> dict:
    n = args.nodes
    slots = grid_names(n)
    posed = slots[:-1] if n > 1 else slots      # one slot without a pose: drawn beside the layout
    out: dict[str, Any] = {"nodes": n}
    t0 = time.monotonic()
    rng = random.Random(1)
    with ConsoleRig(workdir, slots, posed=posed) as rig:
        rig.wait_live(timeout=300)
        out["rig_live_s"] = round(time.monotonic() - t0, 2)
        time.sleep(args.warmup)     # the nodes' clock exchanges slow down once settled: compare like with like
        out["coordinator_cpu_ms_per_s_page_closed"] = _cpu_ms_per_s(args.cpu_seconds)
        profile = workdir / "chromium-profile"
        driver = chromium(profile)
        try:
            t = time.monotonic()
            driver.get(rig.url)
            wait_for(lambda: visible(driver, "login-view"), 60, "the login form")
            out["page_load_ms"] = round(1e3 * (time.monotonic() - t), 1)
            out["page_load_ms_browser"] = driver.execute_script(
                "const n = performance.getEntriesByType('navigation')[0]; return n ? Math.round(n.loadEventEnd) : null;")
            t = time.monotonic()
            log_in(driver, rig.token)
            wait_for(lambda: all_shown(driver, slots, "live"), 120, f"every node live: {slots}")
            out["all_live_ms"] = round(1e3 * (time.monotonic() - t), 1)

            # a change on the coordinator until the page shows it: a slot's gain
            gains = []
            for k in range(args.gain_changes):
                slot, g = slots[k % n], round(0.5 + 0.01 * (k + 1), 2)
                time.sleep(rng.uniform(0.0, 0.5))   # at a random phase of the page's update period
                t = time.monotonic()
                rig.call(lambda: rig.coord.update_slot(slot, gain=g))
                wait_for(lambda: page_gains(driver).get(slot) == f"{g:g}", 30, f"gain {g} of {slot}")
                gains.append(1e3 * (time.monotonic() - t))
            out["gain_update_latency_ms_p50"] = round(float(np.percentile(gains, 50)), 1) if gains else None
            out["gain_update_latency_ms_p99"] = _p99(gains)

            # CPU with the page open (as before with it closed: a still shown, the nodes heartbeating),
            # then a sequence played for the plots
            out["coordinator_cpu_ms_per_s_page_open"] = _cpu_ms_per_s(args.cpu_seconds)
            out["console_cpu_percent_of_core"] = round(
                (out["coordinator_cpu_ms_per_s_page_open"] - out["coordinator_cpu_ms_per_s_page_closed"]) / 10.0, 2)
            # cues: GO until every projector swaps; a crossfade's skew across the nodes (bench/console_cues.py)
            if args.cue_rounds > 0:
                out.update(cue_figures(rig, slots, rounds=args.cue_rounds, fade_s=args.cue_fade))
            out.update(play_figures(rig, driver, slots, args.thumbnail_seconds))
            rig.call(lambda: rig.coord.play_sequence(None, PlaySettings(fps=30, pattern="counter", frames=150, wait=False)))
            time.sleep(2.5)
            driver.save_screenshot(str(screenshot))
            out["screenshot"] = str(screenshot)

            # a node killed until the page shows it lost
            lost = []
            killed = slots[n - min(args.kills, n):]      # --kills 0: none
            if killed:      # the coordinator's "node ... lost" warnings that follow are these, on purpose
                print(f"bench console: killing {', '.join(killed)} (SIGKILL) to time the page's 'lost'",
                      file=sys.stderr, flush=True)
            for slot in killed:
                t = time.monotonic()
                rig.kill_node(slot)
                wait_for(lambda: page_states(driver).get(slot) == "lost", 60, f"{slot} lost")
                lost.append(1e3 * (time.monotonic() - t))
            out["lost_latency_ms"] = [round(v, 1) for v in lost]
            out["update_latency_ms_p99"] = _p99(gains + lost)
            out["snapshots_pushed"] = rig.call(lambda: rig.app.console.app.live.pushes)
        finally:
            driver.quit()
    return out


def screenshot_file(option: str | None, workdir: Path) -> Path:
    """Where the page's screenshot goes: ``--screenshot PNG`` (its folder made), else console.png in
    the run's directory ``workdir``, which goes with it unless ``--keep`` keeps it: a run leaves no
    picture behind that nobody asked for."""
    shot = Path(option) if option else workdir / "console.png"
    shot.parent.mkdir(parents=True, exist_ok=True)
    return shot


def run(args: argparse.Namespace) -> int:
    missing = browser_missing()
    if missing:
        print(f"bench console: {missing}", file=sys.stderr)
        return 2
    print(f"bench console: {args.nodes} nodes, headless Chromium …", file=sys.stderr, flush=True)
    with run_dir(args.keep, f"console-n{args.nodes}") as base:
        shot = screenshot_file(args.screenshot, base)
        result = measure(args, base, shot)
    if not args.screenshot and not args.keep:
        result["screenshot"] = None     # it went with the run's directory
    doc = {"benchmark": "console", "machine": machine(),
           "parameters": {"nodes": args.nodes, "gain_changes": args.gain_changes, "kills": args.kills,
                          "cpu_seconds": args.cpu_seconds, "warmup_s": args.warmup,
                          "thumbnail_seconds": args.thumbnail_seconds, "cue_rounds": args.cue_rounds,
                          "cue_fade_s": args.cue_fade},
           **result}
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":   # pragma: no cover - until `shadowless bench console` is registered
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    configure(parser)
    raise SystemExit(run(parser.parse_args()))
