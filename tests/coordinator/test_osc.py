"""Show control over OSC, against a real coordinator in this process: python-osc's client in a
separate process fires the commands and gets the status back; every command lands in the action
log as osc:<ip>; a refused one is answered with /shadowless/error; a sender off the allow-list is
ignored and logged once; an external timecode moves a playing show. The timecode arithmetic and
rig.toml's [osc] are checked on their own."""
from __future__ import annotations

import asyncio
import json
import logging
import socket
import subprocess
import sys

import cv2
import numpy as np
import pytest
from pythonosc.osc_packet import OscPacket

from coordinator.api import ShowState
from coordinator.assets import AssetStore
from coordinator.console.audit import ActionLog
from coordinator.errors import RigError
from coordinator.osc.config import OscConfig, load_osc, parse_osc
from coordinator.osc.service import OscService, encode
from coordinator.osc.timecode import chase, timecode_seconds
from coordinator.rig import Rig, grid_slots, init_rig
from action_log import action_log_entries
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"o" * 32

#: the show controller: python-osc's client, in its own process. Sends the messages given as JSON,
#: then prints every reply as a JSON line until it has seen each address it waits for.
CLIENT = r"""
import json, sys, time
from pythonosc.udp_client import SimpleUDPClient
port, messages, expect = int(sys.argv[1]), json.loads(sys.argv[2]), set(json.loads(sys.argv[3]))
client = SimpleUDPClient("127.0.0.1", port)
for address, args in messages:
    client.send_message(address, args)
deadline = time.monotonic() + 60
while expect and time.monotonic() < deadline:
    for m in client.get_messages(1.0):
        print(json.dumps([m.address, list(m.params)]), flush=True)
        expect.discard(m.address)
sys.exit(1 if expect else 0)
"""


def _clip(folder, frames=100):
    folder.mkdir()
    for k in range(frames):
        cv2.imwrite(str(folder / f"{k:03d}.png"), np.full((16, 32, 3), 2 * k, np.uint8))
    return folder



def test_show_control_from_another_process(tmp_path, caplog):
    rig_dir = init_rig(tmp_path / "rig", name="osc", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\nallow = ["127.0.0.1"]\n')
    AssetStore(rig_dir).add(_clip(tmp_path / "clip"), name="clip", fps=10)

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), TOKEN) as app:
            coord, osc = app.coordinator, app.osc
            cues = hasattr(coord, "set_cues")
            if cues:        # the cue list (coordinator/cues.py), when this core has one
                from protos.cues import Cue, CueList
                coord.set_cues(CueList((Cue(id="dark", name="house dark", kind="blackout"),
                                        Cue(id="end", name="the end", kind="blackout"))))
            messages = [["/shadowless/gain", ["*", 0.5]], ["/shadowless/blackout", []],
                        ["/shadowless/nope", []]] + ([["/shadowless/go", []]] if cues else []) + \
                       [["/shadowless/status", []]]
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-c", CLIENT, str(osc.port), json.dumps(messages),
                json.dumps(["/shadowless/error", "/shadowless/lost"]), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            out, err = await proc.communicate()
            assert proc.returncode == 0, (out, err)
            replies = {}
            for line in out.decode().splitlines():
                address, args = json.loads(line)
                replies[address] = args
            assert replies["/shadowless/error"][0] == "/shadowless/nope"
            assert "unknown address" in replies["/shadowless/error"][1]
            assert replies["/shadowless/nodes"] == [0, 2] and replies["/shadowless/lost"] == [0, ""]
            if cues:
                assert replies["/shadowless/cue/current"] == ["dark", "house dark"]
                assert replies["/shadowless/cue/next"] == ["end", "the end"]
            log = {e["action"]: e for e in await wait_until_async(
                lambda: [e for e in action_log_entries(rig_dir) if e["who"] == "osc:127.0.0.1"], lambda es: len(es) >= 3,
                what="the commands in the action log")}
            assert (log["osc gain"]["ok"], log["osc blackout"]["ok"], log["osc nope"]["ok"]) == (True, True, False)
            assert "black" in log["osc blackout"]["result"] and "2 slots" in log["osc gain"]["result"]
            assert {s.gain for s in coord.rig.slots.values()} == {0.5}

            # a subscriber hears the status at once, then again when it changes (here from elsewhere)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sub:
                sub.bind(("127.0.0.1", 0))
                sub.setblocking(False)
                sub.sendto(encode("/shadowless/subscribe", ()), ("127.0.0.1", osc.port))
                heard: list[str] = []

                def show_states() -> list[str]:
                    try:
                        while True:
                            for m in OscPacket(sub.recv(65536)).messages:
                                if m.message.address == "/shadowless/show":
                                    heard.append(m.message.params[0])
                    except BlockingIOError:
                        return heard
                assert (await wait_until_async(show_states, what="the status for a new subscriber")) == ["none"]
                coord.play_asset("clip")
                await wait_until_async(show_states, lambda h: {"scheduled", "playing"} & set(h[1:]),
                                       what="the status pushed when the show starts")

            # an external clock 2 s ahead of a playing show makes it seek there
            await wait_until_async(lambda: coord.status().show.state, lambda s: s == "playing",
                                   what="the clip playing")
            frame_now = coord.status().show.frame
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(encode("/shadowless/timecode", (frame_now / 10 + 2.0,)), ("127.0.0.1", osc.port))
            entry = await wait_until_async(
                lambda: [e for e in action_log_entries(rig_dir) if e["action"] == "osc timecode chase"],
                what="the show chasing the timecode")
            assert entry[0]["ok"] and entry[0]["who"] == "osc:127.0.0.1", entry
            assert entry[0]["params"]["drift_ms"] > 1500
            assert coord.status().show.anchor_frame >= frame_now + 20

            # a sender off the allow-list: dropped unread, logged once, nothing done
            strict = OscService(coord, OscConfig(listen=("127.0.0.1", 0), allow=parse_osc(
                {"allow": ["10.9.8.0/24"]}).allow), ActionLog(rig_dir))
            await strict.start()
            try:
                before = len(action_log_entries(rig_dir))
                with caplog.at_level(logging.WARNING, logger="coordinator.osc.service"):
                    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                        for _ in range(3):
                            s.sendto(encode("/shadowless/blackout", ()), ("127.0.0.1", strict.port))
                    await wait_until_async(lambda: strict.ignored.get("127.0.0.1", 0), lambda n: n == 3,
                                           what="three datagrams from 127.0.0.1 ignored")
                said = [r.getMessage() for r in caplog.records if "ignored a message from 127.0.0.1" in r.getMessage()]
                assert len(said) == 1 and "10.9.8.0/24" in said[0]
                assert strict.handled == 0 and len(action_log_entries(rig_dir)) == before
            finally:
                await strict.stop()

    asyncio.run(go())


def _show(state="playing", *, anchor_ns=0, anchor_frame=0, frames=100, loop=False) -> ShowState:
    return ShowState(state=state, frames=frames, rate_num=25, rate_den=1, anchor_ns=anchor_ns,
                     anchor_frame=anchor_frame, loop=loop)


def test_timecode_reading_and_the_chase_arithmetic():
    assert timecode_seconds("00:01:02:05", 25) == pytest.approx(62.2)
    assert timecode_seconds("01:00:00;00", 30) == 3600.0
    assert timecode_seconds("00:00:10.5", 25) == 10.5 and timecode_seconds(7, 25) == 7.0
    for bad in ("1:2", "00:61:00:00", "00:00:00:25", -1.0, True, "soon"):
        with pytest.raises(ValueError):
            timecode_seconds(bad, 25)
    s = 1_000_000_000
    # the show at frame 50 (2.0 s) at rig time 2 s; the clock says 2.05 s: within the 100 ms threshold
    assert chase(2.05, 2 * s, _show(), 2 * s, threshold_s=0.1, lead_ns=s // 5) is None
    # the clock says 3.0 s (received 0.1 s ago): 1.1 s ahead of the show; seek to the first frame
    # boundary of the clock at least 200 ms ahead: 3.1 + 0.2 = 3.3 s = frame 82.5 -> frame 83 at 3.32 s on the clock
    seek = chase(3.0, 1_900_000_000, _show(), 2 * s, threshold_s=0.1, lead_ns=s // 5)
    assert seek.frame == 83 and seek.at_ns == 2 * s + 220_000_000 and seek.drift_s == pytest.approx(1.1)
    # a looping show is compared the shorter way round: 3.9 s into a 4 s loop is 0.1 s behind 0.0 s
    seek = chase(3.9, 0, _show(loop=True), 0, threshold_s=0.05, lead_ns=s // 5)
    assert seek.drift_s == pytest.approx(-0.1) and seek.frame == (98 + 5) % 100
    # a show that does not play, or a clock outside the asset, is left alone
    assert chase(9.0, 0, _show("paused"), 0, threshold_s=0.1, lead_ns=0) is None
    assert chase(9.0, 0, _show(), 0, threshold_s=0.1, lead_ns=0) is None


def test_osc_settings_in_rig_toml(tmp_path):
    cfg = parse_osc({"listen": "0.0.0.0:9000", "allow": ["10.0.0.0/24", "127.0.0.1"], "feedback": "10.0.0.9:9001"})
    assert cfg.listen == ("0.0.0.0", 9000) and cfg.feedback == (("10.0.0.9", 9001),)
    assert cfg.allows("10.0.0.77") and cfg.allows("::ffff:127.0.0.1") and not cfg.allows("10.0.1.1")
    assert not OscConfig().allows("192.168.1.2") and OscConfig().allows("::1") and OscConfig().listen is None
    rig_dir = init_rig(tmp_path / "rig", name="osc", slots=["a"], width=32, height=32, content_width=64,
                       content_height=32)
    assert load_osc(rig_dir).listen is None, "off unless [osc] names where to listen"
    for table, words in [('listen = "9000"', "HOST:PORT"), ('listen = "127.0.0.1:1"\nallow = ["ten"]', "ten"),
                         ('lisen = "127.0.0.1:9000"', "unknown key lisen")]:
        (rig_dir / "rig.toml").write_text((rig_dir / "rig.toml").read_text().split("\n[osc]")[0] + f"\n[osc]\n{table}\n")
        with pytest.raises(RigError) as e:
            load_osc(rig_dir)
        assert words in str(e.value) and "[osc]" in str(e.value) and "\n" not in str(e.value)


def test_stop_ends_when_it_meets_a_wake_up(tmp_path):
    """asyncio.wait_for (3.11) drops a cancel that meets its just-set event: the status loop ran on
    and stop() awaited it forever (a command recorded, or a timecode, right as the coordinator stops)."""
    rig_dir = init_rig(tmp_path / "rig", name="osc", slots=["a"], width=32, height=32, content_width=64,
                       content_height=32)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\n')

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), TOKEN) as app:
            osc = app.osc
            for _ in range(5):      # the status loop reaches its wait for the next check
                await asyncio.sleep(0)
            osc.external_clock(1.0, app.coordinator.rig_now(), "osc:127.0.0.1", "127.0.0.1")   # wakes the loop
            async with asyncio.timeout(30):
                await osc.stop()

    asyncio.run(go())
