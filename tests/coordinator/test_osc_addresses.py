"""Every OSC address docs/show-control.md names is one show control answers, and it answers no other;
the commands the other OSC tests leave out (back, play, pause, resume, stop, a gain on one slot,
unsubscribe) and the status reply (its ``/shadowless/showing`` too) do what the page says, driven by a
show controller in a process of its own (python-osc's client): the effect shows in the coordinator's
status and action log, a subscriber hears the change, a wrongly typed argument of any address is
answered with one ``/shadowless/error ADDRESS REASON`` line (nothing changes, no traceback is logged),
and a subscriber that unsubscribes, by itself or by its PORT, hears nothing more. A subscription lasts
10 minutes unless renewed, and rig.toml's feedback targets hear every change unasked.

One coordinator (in this process, serving from an event loop on a thread of its own) and one controller
process serve the module's tests: a rig of two slots whose content is an image "house", with a clip
and a cue list of three cues. Each test sets up the state it starts from."""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import re
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from coordinator.assets import AssetStore
from coordinator.console.audit import ActionLog
from coordinator.osc import commands, service
from coordinator.osc.config import OscConfig
from coordinator.osc.service import OscService
from coordinator.rig import Content, Rig, grid_slots, init_rig
from protos.cues import Cue, CueList
from action_log import action_log_entries
from inprocess_coordinator import inprocess_coordinator
from waits import wait_until

TOKEN = b"e" * 32
PAGE = Path(__file__).resolve().parents[2] / "docs" / "show-control.md"
OSC = "/shadowless"
CUES = CueList((Cue(id="1", name="one", kind="blackout"),
                Cue(id="2", name="two", kind="still", target="content"),
                Cue(id="3", name="three", kind="blackout")))
CONTENT = "the rig's content: house"

#: the show controller: python-osc's clients "a" and "b" (each sends from, and hears on, a port of its
#: own) and "c", a bare UDP port such as a show controller listens on (sends built by python-osc).
#: Reads ``[NAME, ADDRESS, ARGS]`` lines on stdin and sends each; prints ``["ready", C_PORT]``, then
#: every message a client hears as ``[NAME, ADDRESS, ARGS]``. Ends when stdin closes.
CONTROLLER = r"""
import json, socket, sys, threading
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.udp_client import SimpleUDPClient

port = int(sys.argv[1])
lock = threading.Lock()

def say(*line):
    with lock:
        print(json.dumps(line), flush=True)

def hear(name, messages):
    for message in messages():
        say(name, message.address, list(message.params))

def client_messages(client):
    def messages():
        while True:
            yield from client.get_messages(1.0)
    return messages

def target_messages():
    while True:
        yield OscMessage(target.recv(65536))

clients = {name: SimpleUDPClient("127.0.0.1", port) for name in ("a", "b")}
target = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
target.bind(("127.0.0.1", 0))
threading.Thread(target=hear, args=("c", target_messages), daemon=True).start()
hearing = set()
say("ready", target.getsockname()[1])
for line in sys.stdin:
    name, address, args = json.loads(line)
    if name == "c":
        b = OscMessageBuilder(address=address)
        for a in args:
            b.add_arg(a)
        target.sendto(b.build().dgram, ("127.0.0.1", port))
        continue
    clients[name].send_message(address, args)
    if name not in hearing:     # its port exists once it has sent
        hearing.add(name)
        threading.Thread(target=hear, args=(name, client_messages(clients[name])), daemon=True).start()
"""


class Controller:
    """The controller process: :meth:`send` from a client, :attr:`heard` what the clients heard."""

    def __init__(self, port: int):
        self.proc = subprocess.Popen([sys.executable, "-c", CONTROLLER, str(port)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.heard: list[tuple[str, str, list]] = []     # (client, address, args), in arrival order
        self.target_port: int | None = None
        self._reader = threading.Thread(target=self._read, name="osc controller's output", daemon=True)
        self._reader.start()
        wait_until(lambda: self.target_port or self.proc.poll() is not None, what="the controller ready")
        assert self.proc.poll() is None, self.proc.stderr.read()

    def _read(self) -> None:
        for line in self.proc.stdout:
            name, *rest = json.loads(line)
            if name == "ready":
                self.target_port = rest[0]
            else:
                self.heard.append((name, rest[0], rest[1]))

    def send(self, name: str, address: str, *args) -> None:
        self.proc.stdin.write(json.dumps([name, address, list(args)]) + "\n")
        self.proc.stdin.flush()

    def mark(self) -> int:
        """Where the messages heard from now on start (for :meth:`since`)."""
        return len(self.heard)

    def since(self, mark: int, name: str) -> list[tuple[str, list]]:
        return [(address, args) for n, address, args in self.heard[mark:] if n == name]

    def wait(self, mark: int, name: str, address: str, done=lambda args: True, *, what: str) -> list:
        """The arguments of the first message at ``address`` that ``name`` heard since ``mark`` and that
        ``done`` accepts."""
        found = wait_until(lambda: [args for a, args in self.since(mark, name) if a == address and done(args)],
                           what=f"{name} to hear {address}: {what}")
        return found[0]

    def subscribe(self, name: str) -> None:
        """``name`` subscribes and has heard the status that answers it."""
        mark = self.mark()
        self.send(name, f"{OSC}/subscribe")
        self.wait(mark, name, f"{OSC}/lost", what="the status answering its subscription")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(timeout=30)
        self.proc.stdout.close()
        self.proc.stderr.close()


class Served:
    """A coordinator served from an event loop on a thread of its own; :meth:`call` runs a function
    in that loop (the coordinator is not thread-safe) and returns what it returned."""

    def __init__(self, rig_dir: Path):
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="osc addresses' coordinator", daemon=True)
        self.thread.start()
        self._stack = contextlib.AsyncExitStack()
        try:
            self.app = self._run(self._stack.enter_async_context(inprocess_coordinator(Rig(rig_dir), TOKEN)))
        except BaseException:
            self._end_loop()
            raise
        self.coord = self.app.coordinator

    def _run(self, coro, timeout: float = 120.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn, *args, **kwargs):
        async def run():
            return fn(*args, **kwargs)
        return self._run(run())

    def wait_for(self, coro_fn):
        """Await ``coro_fn()`` in the coordinator's loop; what it returned."""
        return self._run(coro_fn())

    def close(self) -> None:
        try:
            self._run(self._stack.aclose())
        finally:
            self._end_loop()

    def _end_loop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=30)
        self.loop.run_until_complete(self.loop.shutdown_default_executor())
        self.loop.close()


class Show:
    def __init__(self, rig_dir: Path, served: Served, controller: Controller):
        self.rig_dir, self.served, self.osc = rig_dir, served, controller

    def status(self):
        return self.served.call(self.served.coord.status)

    def current_cue(self) -> str | None:
        state = self.served.call(self.served.coord.cue_state)
        return None if state.current is None else state.cues[state.current].id

    def observed(self) -> tuple:
        """What a command could change: the show, what the projectors show, the cue, the gains."""
        st = self.status()
        gains = self.served.call(lambda: {n: s.gain for n, s in self.served.coord.rig.slots.items()})
        return st.show.state, st.show.asset_id, st.show.loop, st.showing, self.current_cue(), gains

    def entries(self, action: str) -> list[dict]:
        return [e for e in action_log_entries(self.rig_dir) if e["action"] == action]

    def logged(self, action: str, before: int, what: str) -> dict:
        """The action log's entry for ``action`` after the first ``before`` of them (waits for it)."""
        return wait_until(lambda: self.entries(action)[before:], what=f"the action log's {action!r}: {what}")[0]

    def settle(self, address: str, *args, probe, done, what: str) -> None:
        """Send ``address`` from "a"; wait for its effect (``done(probe())``) and its action log entry."""
        action = "osc " + address.removeprefix(OSC + "/")
        before = len(self.entries(action))
        self.osc.send("a", address, *args)
        wait_until(probe, done, what=what)
        assert self.logged(action, before, what)["ok"]


def _rig(work: Path) -> Path:
    rig_dir = init_rig(work / "rig", name="oscaddr", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\nallow = ["127.0.0.1"]\n')
    clip = work / "clip"
    clip.mkdir()
    for k in range(50):
        cv2.imwrite(str(clip / f"{k:03d}.png"), np.full((16, 32, 3), 4 * k, np.uint8))
    AssetStore(rig_dir).add(clip, name="clip", fps=10)
    Rig(rig_dir).set_content(Content(np.full((32, 64, 3), 90, np.uint8), name="house"))
    return rig_dir


@pytest.fixture(scope="module")
def show(tmp_path_factory):
    rig_dir = _rig(tmp_path_factory.mktemp("osc-addresses"))
    served = Served(rig_dir)
    try:
        served.call(served.coord.set_cues, CUES)
        controller = Controller(served.app.osc.port)
        try:
            yield Show(rig_dir, served, controller)
        finally:
            controller.close()
    finally:
        served.close()


@pytest.fixture(autouse=True)
def no_tracebacks(caplog):
    """Whatever the controller sends, the coordinator logs no traceback and no error."""
    yield
    bad = [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR or "Traceback" in r.getMessage()]
    assert not bad, [f"{r.name}: {r.getMessage()}" for r in bad]


def _page_table(section: str) -> set[str]:
    """The addresses in the first column of the table under ``## section`` of docs/show-control.md."""
    text = PAGE.read_text()
    assert f"\n## {section}\n" in text, f"docs/show-control.md has no section {section!r}"
    body = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    found = set()
    for row in body.splitlines():
        cells = re.split(r"(?<!\\)\|", row)     # a cell may hold an escaped \| (SLOT\|*)
        if len(cells) > 2:
            found |= {words.split()[0] for words in re.findall(r"`([^`]+)`", cells[1]) if words.startswith("/")}
    return found


def test_the_page_names_every_address_show_control_answers_and_no_other():
    page = _page_table("Address space")
    assert len(page) >= 13, page
    answered = set(service.ANSWERED)
    assert page == answered, (f"named on docs/show-control.md but not answered: {sorted(page - answered)}; "
                              f"answered but not on the page: {sorted(answered - page)}")
    assert {a.path for a in commands.ADDRESSES} == answered, "the addresses' own table (their usage) differs"
    assert f"`{OSC}/error ADDRESS REASON`" in PAGE.read_text()


def test_status_is_the_six_messages_the_page_names(show):
    """/shadowless/status answers the sender with the page's status table, /showing saying what the
    coordinator's status says; the status is no entry of the action log."""
    show.settle(f"{OSC}/stop", probe=lambda: show.status().showing, done=lambda s: s == CONTENT,
                what="the rig's content shown")
    logged = len(action_log_entries(show.rig_dir))      # the stop's entry among them
    mark = show.osc.mark()
    show.osc.send("a", f"{OSC}/status")
    show.osc.wait(mark, "a", f"{OSC}/lost", what="the status reply's last message")
    reply = dict(show.osc.since(mark, "a"))
    assert set(reply) == _page_table("Status and feedback"), reply
    st = show.status()
    assert reply[f"{OSC}/showing"] == [st.showing] == [CONTENT]
    assert reply[f"{OSC}/nodes"] == [0, 2] and reply[f"{OSC}/lost"] == [0, ""]
    state, asset, frame, frames = reply[f"{OSC}/show"]
    assert (state, isinstance(frame, int), isinstance(frames, int)) == (st.show.state, True, True)
    current = show.current_cue()
    assert reply[f"{OSC}/cue/current"][0] == (current or "")
    # the next entry is that of a command sent after the status: the status itself left none
    stops = len(show.entries("osc stop"))
    show.osc.send("a", f"{OSC}/stop")
    show.logged("osc stop", stops, "the stop after the status")
    entries = action_log_entries(show.rig_dir)
    assert entries[logged]["action"] == "osc stop" and entries[logged]["who"] == "osc:127.0.0.1", entries[logged:]


def test_back_fires_the_cue_before_the_current_one(show):
    show.osc.subscribe("b")
    show.settle(f"{OSC}/jump", "3", probe=lambda: (show.current_cue(), show.status().showing),
                done=lambda seen: seen == ("3", "black (cue 3)"), what="cue 3 current, black shown")
    backs = len(show.entries("osc back"))
    for cue, name, showing in (("2", "two", "cue 2: house"), ("1", "one", "black (cue 1)")):
        mark = show.osc.mark()
        show.settle(f"{OSC}/back", probe=lambda: (show.current_cue(), show.status().showing),
                    done=lambda seen, cue=cue, showing=showing: seen == (cue, showing),
                    what=f"cue {cue} current after /back, its picture shown")   # a still shows when decoded
        show.osc.wait(mark, "b", f"{OSC}/cue/current", lambda a, c=[cue, name]: a == c,
                      what=f"cue {cue} pushed to the subscriber")
        show.osc.wait(mark, "b", f"{OSC}/showing", lambda a, s=[showing]: a == s, what=f"{showing} pushed")
        entry = show.logged("osc back", backs, f"the /back to cue {cue}")
        backs += 1
        assert entry["ok"] and entry["who"] == "osc:127.0.0.1" and cue in entry["result"], entry

    mark = show.osc.mark()      # nothing before cue 1: refused in one line, cue 1 stays
    show.osc.send("a", f"{OSC}/back")
    address, reason = show.osc.wait(mark, "a", f"{OSC}/error", what="the refusal of /back at the first cue")
    assert address == f"{OSC}/back" and "no cue before" in reason, reason
    assert show.current_cue() == "1"
    assert not show.logged("osc back", backs, "the refused /back")["ok"]


def test_play_pause_resume_and_stop(show):
    show.osc.subscribe("b")
    show.settle(f"{OSC}/stop", probe=lambda: show.status().showing, done=lambda s: s == CONTENT,
                what="the rig's content shown")
    before = {a: len(show.entries(f"osc {a}")) for a in ("play", "pause", "resume", "stop")}

    mark = show.osc.mark()
    show.osc.send("a", f"{OSC}/play", "clip", 1)      # LOOP 1: it loops, so it still plays below
    st = wait_until(show.status, lambda s: s.show.state == "playing", what="the clip playing").show
    assert st.name == "clip" and st.loop and st.frames == 50
    assert show.osc.wait(mark, "b", f"{OSC}/show", lambda a: a[0] == "playing",
                         what="the show playing")[1:2] == ["clip"]

    mark = show.osc.mark()
    show.osc.send("a", f"{OSC}/pause")
    st = wait_until(show.status, lambda s: s.show.state == "paused" and s.show.now_ns >= s.show.change_at_ns,
                    what="the clip paused, the pause in effect").show
    assert 0 <= st.frame < 50
    later = wait_until(show.status, lambda s: s.show.now_ns >= st.now_ns + 3 * 10**9 // 10,
                       what="three frame periods later").show
    assert (later.state, later.frame) == ("paused", st.frame), "the paused show holds its frame"
    told = show.osc.wait(mark, "b", f"{OSC}/show", lambda a: a[0] == "paused", what="the show paused")
    assert told[1] == "clip" and told[3] == 50, told

    mark = show.osc.mark()
    show.osc.send("a", f"{OSC}/resume")
    wait_until(show.status, lambda s: s.show.state == "playing", what="the clip playing again")
    show.osc.wait(mark, "b", f"{OSC}/show", lambda a: a[0] == "playing", what="the show playing again")

    mark = show.osc.mark()
    show.osc.send("a", f"{OSC}/stop")
    st = wait_until(show.status, lambda s: s.show.state == "stopped", what="the clip stopped")
    assert st.showing == CONTENT
    show.osc.wait(mark, "b", f"{OSC}/showing", lambda a: a == [CONTENT], what="the content again")

    for action, words in (("play", "clip"), ("pause", "pause: clip"), ("resume", "resume: clip"), ("stop", CONTENT)):
        entry = show.logged(f"osc {action}", before[action], f"the /{action}")
        assert entry["ok"] and entry["who"] == "osc:127.0.0.1" and words in entry["result"], entry

    mark = show.osc.mark()      # nothing plays: nothing to pause, said in one line
    show.osc.send("a", f"{OSC}/pause")
    address, reason = show.osc.wait(mark, "a", f"{OSC}/error", what="the refusal to pause nothing")
    assert address == f"{OSC}/pause" and "nothing to pause" in reason and "\n" not in reason, reason


def test_gain_on_one_slot(show):
    gains = len(show.entries("osc gain"))
    show.settle(f"{OSC}/gain", "r0c1", 0.25, what="slot r0c1's gain 0.25",
                probe=lambda: show.served.call(lambda: show.served.coord.rig.slots["r0c1"].gain),
                done=lambda g: g == 0.25)
    assert show.served.call(lambda: show.served.coord.rig.slots["r0c0"].gain) != 0.25
    entry = show.logged("osc gain", gains, "the gain on r0c1")
    assert entry["ok"] and "slot r0c1 gain 0.25" in entry["result"], entry


def test_timecode_as_hh_mm_ss_ff_moves_a_playing_show(show):
    """A timecode "hh:mm:ss:ff" (timecode_fps: 25 by default) 1.5 s ahead of the playing show: it seeks."""
    show.settle(f"{OSC}/play", "clip", 1, probe=lambda: show.status().show.state, done=lambda s: s == "playing",
                what="the looped clip playing")
    chases = len(show.entries("osc timecode chase"))
    st = show.status().show
    ticks = int(((st.frame / st.fps + 1.5) % (st.frames / st.fps)) * 25)     # the clip loops: 50 frames at 10 fps
    tc = f"00:00:{ticks // 25:02d}:{ticks % 25:02d}"
    show.osc.send("a", f"{OSC}/timecode", tc)
    entry = show.logged("osc timecode chase", chases, f"the show chasing {tc}")
    assert entry["ok"] and entry["who"] == "osc:127.0.0.1" and entry["params"]["drift_ms"] > 500, entry
    show.settle(f"{OSC}/stop", probe=lambda: show.status().show.state, done=lambda s: s == "stopped",
                what="the clip stopped")


#: (address, a wrongly typed or counted argument list, words its one-line refusal holds)
WRONG = [
    ("go", [1], "takes no arguments"),
    ("back", ["x"], "takes no arguments"),
    ("jump", [1.5], "whole number"),
    ("jump", [True], "the cue's id"),
    ("play", [42], "the asset"),
    ("play", ["clip", "sometimes"], "LOOP must be 0 or 1"),
    ("pause", [1], "takes no arguments"),
    ("resume", ["x"], "takes no arguments"),
    ("stop", [0.5], "takes no arguments"),
    ("blackout", ["now"], "takes no arguments"),
    ("gain", ["r0c0", "loud"], "VALUE must be a number"),
    ("gain", [1, 0.5], "SLOT (a string"),
    ("subscribe", ["x"], "PORT must be"),
    ("subscribe", [9001.5], "PORT must be"),
    ("unsubscribe", ["x"], "PORT must be"),
    ("timecode", ["soon"], "timecode must be"),
    ("nope", [], "unknown address"),
]


def test_a_wrongly_typed_argument_is_refused_in_one_line_and_changes_nothing(show):
    show.settle(f"{OSC}/jump", "2", probe=lambda: (show.current_cue(), show.status().showing),
                done=lambda seen: seen == ("2", "cue 2: house"), what="cue 2 current, its still shown")
    before = show.observed()
    logged = len(action_log_entries(show.rig_dir))
    for name, args, words in WRONG:
        mark = show.osc.mark()
        show.osc.send("a", f"{OSC}/{name}", *args)
        address, reason = show.osc.wait(mark, "a", f"{OSC}/error", what=f"the refusal of /{name} {args!r}")
        assert address == f"{OSC}/{name}" and words in reason, (name, args, reason)
        assert "\n" not in reason and len(reason) < 300, reason
        assert [a for a, _ in show.osc.since(mark, "a")] == [f"{OSC}/error"], show.osc.since(mark, "a")
    assert show.observed() == before
    # the rig commands' refusals are entries of the action log, each with its reason
    refused = {name: words for name, _, words in WRONG if name not in ("subscribe", "unsubscribe", "timecode")}
    count = sum(1 for name, _, _ in WRONG if name in refused)
    entries = wait_until(lambda: action_log_entries(show.rig_dir)[logged:], lambda es: len(es) >= count,
                         what=f"{count} refusals in the action log")
    assert len(entries) == count and all(not e["ok"] and e["who"] == "osc:127.0.0.1" for e in entries), entries
    assert sorted(e["action"] for e in entries) == sorted(f"osc {name}" for name, _, _ in WRONG if name in refused)


def test_unsubscribe_stops_the_feedback(show):
    """b subscribes itself and unsubscribes; a subscribes port c (as TouchDesigner sends a number: a
    float) and unsubscribes it by its PORT; a change then reaches a, still subscribed, and neither b
    nor c."""
    osc = show.osc
    show.settle(f"{OSC}/stop", probe=lambda: show.status().showing, done=lambda s: s == CONTENT,
                what="the rig's content shown")
    show.osc.subscribe("a")
    show.osc.subscribe("b")
    mark = osc.mark()
    osc.send("a", f"{OSC}/subscribe", float(osc.target_port))
    assert osc.wait(mark, "c", f"{OSC}/showing", what="the status at port c, subscribed by a") == [CONTENT]
    osc.wait(mark, "c", f"{OSC}/lost", what="the whole status at port c")

    osc.send("b", f"{OSC}/unsubscribe")
    osc.send("a", f"{OSC}/unsubscribe", osc.target_port)
    mark = osc.mark()       # a refusal each, asked after the unsubscriptions: whatever was on its way came before
    for name in ("b", "c"):
        osc.send(name, f"{OSC}/nope")
    for name in ("b", "c"):
        osc.wait(mark, name, f"{OSC}/error", what="the first marker")

    mark = osc.mark()
    osc.send("a", f"{OSC}/blackout")
    osc.wait(mark, "a", f"{OSC}/showing", lambda args: args == ["black (blackout)"],
             what="the blackout pushed to a, still subscribed")
    assert show.status().showing == "black (blackout)"
    for name in ("b", "c"):
        osc.send(name, f"{OSC}/nope")
    for name in ("b", "c"):
        osc.wait(mark, name, f"{OSC}/error", what="the second marker")
        heard = osc.since(mark, name)
        assert [a for a, _ in heard] == [f"{OSC}/error"], f"{name} heard {heard} after it unsubscribed"
    osc.send("a", f"{OSC}/unsubscribe")


def test_a_subscription_lasts_ten_minutes_unless_renewed(show):
    """A second show control on the same coordinator, its clock the test's: b's subscription carries
    the changes for 600 s, a renewal another 600 s from then, and then no more (a, subscribed later,
    still hears the change that b no longer does)."""
    now = [1000.0]
    svc = OscService(show.served.coord, OscConfig(listen=("127.0.0.1", 0)), ActionLog(show.rig_dir),
                     clock=lambda: now[0])
    show.served.wait_for(svc.start)
    osc = Controller(svc.port)
    try:
        def change(address: str, showing: str, *, heard_by: str, what: str) -> None:
            mark = osc.mark()
            osc.send("a", address)
            wait_until(lambda: show.status().showing, lambda s: s == showing, what=what)
            osc.wait(mark, heard_by, f"{OSC}/showing", lambda args: args == [showing], what=f"{what}, pushed")

        osc.send("a", f"{OSC}/blackout")
        wait_until(lambda: show.status().showing, lambda s: s == "black (blackout)", what="the blackout")
        osc.subscribe("b")          # at 1000 s: until 1600 s
        now[0] = 1599.0
        change(f"{OSC}/stop", CONTENT, heard_by="b", what="the content, 599 s into b's subscription")
        osc.subscribe("b")          # renewed: until 2199 s
        now[0] = 2100.0
        change(f"{OSC}/blackout", "black (blackout)", heard_by="b", what="black, 500 s after b renewed")
        osc.subscribe("a")          # the witness: until 2700 s
        now[0] = 2200.0
        mark = osc.mark()
        change(f"{OSC}/stop", CONTENT, heard_by="a", what="the content, 601 s after b renewed")
        osc.send("b", f"{OSC}/nope")            # a marker: anything pushed to b came before its answer
        osc.wait(mark, "b", f"{OSC}/error", what="the marker")
        assert [a for a, _ in osc.since(mark, "b")] == [f"{OSC}/error"], osc.since(mark, "b")
    finally:
        osc.close()
        show.served.wait_for(svc.stop)


def test_feedback_targets_hear_every_change_unasked(show):
    """rig.toml's ``feedback``: a show control whose target is port c sends c the status when it starts
    and on each change (here one made through the module's show control), without c subscribing."""
    osc = show.osc
    showing = show.status().showing
    mark = osc.mark()
    svc = OscService(show.served.coord, OscConfig(listen=("127.0.0.1", 0), feedback=(("127.0.0.1", osc.target_port),)),
                     ActionLog(show.rig_dir))
    show.served.wait_for(svc.start)
    try:
        assert osc.wait(mark, "c", f"{OSC}/showing", what="the status at start") == [showing]
        osc.wait(mark, "c", f"{OSC}/lost", what="the whole status at start")
        change, after = (f"{OSC}/blackout", "black (blackout)") if showing != "black (blackout)" else \
            (f"{OSC}/stop", CONTENT)
        mark = osc.mark()
        osc.send("a", change)
        osc.wait(mark, "c", f"{OSC}/showing", lambda args: args == [after], what=f"{after}, pushed to the target")
    finally:
        show.served.wait_for(svc.stop)
