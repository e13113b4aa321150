"""MIDI timecode: the decoding of quarter frames and full frames at every rate (2 s of running MTC
generated per rate, every decoded timecode checked, and where the clock is when piece 7 arrives),
the chase it drives on a real coordinator (the same as OSC timecode's: a seek onto the clock, and
none once the clock stopped), and the refusals without the library. A real MIDI port (mido's
virtual port, through the ALSA sequencer) is used where the machine has one; where it has none,
the same test checks the one-line refusal instead, so nothing skips."""
from __future__ import annotations

import asyncio
import os
import random
import sys
from fractions import Fraction

import cv2
import numpy as np
import pytest

from coordinator.assets import AssetStore
from coordinator.console.audit import ActionLog
from coordinator.errors import CoordinatorError, RigError
from coordinator.osc.config import load_osc
from coordinator.osc.mtc import (RATES, MtcDecoder, Timecode, from_frame_number, full_frame, quarter_frames)
from coordinator.osc.mtc_input import ALSA_SEQ, MidiUnavailable, MtcInput, choose_port, port_names
from coordinator.osc.service import OscService
from coordinator.rig import Rig, grid_slots, init_rig
from waits import wait_until, wait_until_async
from action_log import action_log_entries
from inprocess_coordinator import inprocess_coordinator

NS = 1_000_000_000


def running_mtc(start: Timecode, seconds: float) -> list[tuple[int, bytes]]:
    """What a sender running from ``start`` sends for ``seconds``: four quarter frames a frame,
    pieces 0..7 over two frames carrying the timecode of the first; each with its send instant (ns
    from the start), with a timing clock byte (F8) now and then, as a sequencer sends."""
    fps = start.fps
    n0, out = start.frame_number, []
    groups = int(seconds * fps) // 2
    for g in range(groups):
        tc = from_frame_number(n0 + 2 * g, start.rate)
        qf = quarter_frames(tc)
        for k in range(8):
            t = Fraction(8 * g + k, 4) / fps
            msg = qf[2 * k:2 * k + 2]
            if k == 3:
                msg = msg[:1] + b"\xf8" + msg[1:]      # real time bytes may sit inside a message
            out.append((int(t * NS), msg))
    return out


@pytest.mark.parametrize("rate", sorted(RATES))
def test_two_seconds_of_running_mtc_decode_frame_by_frame(rate):
    # start a second before a minute's end: 29.97 drop-frame skips frames 0 and 1 of minute 1
    start = Timecode(0, 0, 59, 0, rate)
    sent = running_mtc(start, 2.0)
    rng = random.Random(rate)
    dec = MtcDecoder()
    readings = []
    for t, msg in sent:             # each message as it arrives, now and then in two pieces
        cut = rng.randint(1, len(msg))
        readings += dec.feed(msg[:cut], t) + dec.feed(msg[cut:], t)
    fps = start.fps
    groups = len(sent) // 8
    assert len(readings) == groups >= int(2 * fps) // 2 - 1
    for g, r in enumerate(readings):
        expected = from_frame_number(start.frame_number + 2 * g, rate)
        assert r.timecode == expected and r.kind == "quarter", (g, r.timecode, expected)
        # piece 7 of group g arrives at (8g + 7)/4 frames after the start: the reading is the clock then
        arrival = start.seconds_since_midnight + float(Fraction(8 * g + 7, 4) / fps)
        assert r.at_ns == int(Fraction(8 * g + 7, 4) / fps * NS)
        assert r.seconds == pytest.approx(arrival, abs=1e-9)
    if RATES[rate][1]:
        names = [str(r.timecode) for r in readings]
        assert "00:00:59;28" in names and "00:01:00;02" in names and "00:01:00;00" not in names
    assert dec.skipped == 0

    # every frame of those 2 s as a full frame (a locate): exactly that timecode, no compensation
    dec = MtcDecoder()
    for k in range(int(2 * fps)):
        tc = from_frame_number(start.frame_number + k, rate)
        (r,) = dec.feed(full_frame(tc, device=k % 128), 7)
        assert (r.timecode, r.kind, r.at_ns) == (tc, "full", 7)
        assert r.seconds == pytest.approx(float(tc.frame_number / fps), abs=1e-9)


def test_frame_numbers_and_what_the_decoder_refuses():
    for rate in RATES:
        for n in range(0, 3 * 17982, 13):
            assert from_frame_number(n, rate).frame_number == n
    assert str(from_frame_number(17982, 2)) == "00:10:00;00" and str(from_frame_number(1800, 2)) == "00:01:00;02"
    assert Timecode(1, 0, 0, 0, 2).seconds_since_midnight == pytest.approx(3600, abs=0.01), "drop-frame keeps time"
    with pytest.raises(ValueError, match="dropped"):
        Timecode(0, 1, 0, 1, 2)
    tc = Timecode(10, 20, 30, 12, 1)
    dec = MtcDecoder()
    backwards = b"".join(quarter_frames(tc)[2 * k:2 * k + 2] for k in reversed(range(8)))
    assert dec.feed(backwards, 0) == [], "a clock running backwards is not chased"
    qf = quarter_frames(tc)
    assert dec.feed(qf[:6] + qf[8:], 0) == [], "a lost piece: no reading from a half group"
    assert [r.timecode for r in dec.feed(qf, 0)] == [tc], "the next whole group reads again"
    # other messages between them are skipped: a note on, a song position, another SysEx
    mixed = b"\x90\x3c\x40" + qf[:8] + b"\xf2\x10\x20" + qf[8:] + b"\xf0\x7e\x7f\x06\x01\xf7"
    assert [r.timecode for r in MtcDecoder().feed(mixed, 0)] == [tc]
    assert MtcDecoder().feed(b"\xf0\x7f\x7f\x01\x01\x20\x3c\x00\x00\xf7", 0) == [], "minute 60 is no timecode"


def _clip(folder, frames=100):
    folder.mkdir()
    for k in range(frames):
        cv2.imwrite(str(folder / f"{k:03d}.png"), np.full((16, 32, 3), k % 128 * 2, np.uint8))
    return folder



def test_mtc_drives_the_chase_and_stops_driving_it_when_it_stops(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="mtc", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\n')
    AssetStore(rig_dir).add(_clip(tmp_path / "clip", 200), name="clip", fps=10)

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), b"m" * 32) as app:
            coord, osc = app.coordinator, app.osc
            # the port's bytes, as rtmidi hands them over in its thread (no MIDI system here: see the last test)
            port = MtcInput("desk", osc.mtc_readings, coord.rig_now)
            coord.play_asset("clip")
            await wait_until_async(lambda: coord.status().show.state, lambda s: s == "playing", what="the clip playing")
            frame_now = coord.status().show.frame
            target = from_frame_number(round((frame_now / 10 + 5.0) * 25), 1)    # 5 s ahead, at 25 fps
            await asyncio.to_thread(port.feed, quarter_frames(target))
            entry = await wait_until_async(
                lambda: [e for e in action_log_entries(rig_dir) if e["action"] == "mtc timecode chase"],
                what="the show chasing MIDI timecode")
            assert entry[0]["ok"] and entry[0]["who"] == "mtc:desk" and entry[0]["address"] == "midi", entry
            assert entry[0]["params"]["drift_ms"] > 4500
            assert coord.status().show.anchor_frame >= frame_now + 45

            # MTC stops: a second later the clock is stale, and a show moved elsewhere stays there
            await wait_until_async(lambda: osc.clock_fresh, lambda fresh: not fresh, what="the clock going stale")
            coord.show_control("seek", frame=0)
            await wait_until_async(lambda: coord.status().show, lambda s: s.state == "playing" and s.frame >= 15,
                                   what="the show playing on from frame 0 (1.5 s)")
            assert len([e for e in action_log_entries(rig_dir) if e["action"] == "mtc timecode chase"]) == 1

    asyncio.run(go())


def test_without_the_library_mtc_refuses_in_one_line_naming_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mido", None)      # as on a coordinator installed without [midi]
    with pytest.raises(MidiUnavailable) as e:
        port_names()
    assert "shadowless[midi]" in str(e.value) and "\n" not in str(e.value)
    rig_dir = init_rig(tmp_path / "rig", name="mtc", slots=["a"], width=32, height=32, content_width=64,
                       content_height=32)

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), b"m" * 32) as app:
            with open(rig_dir / "rig.toml", "a") as f:
                f.write('\n[osc]\nmtc_port = "MIDI Interface"\n')
            config = load_osc(rig_dir)
            assert config.mtc_port == "MIDI Interface" and config.listen is None and config.on
            service = OscService(app.coordinator, config, ActionLog(rig_dir))
            with pytest.raises(MidiUnavailable, match=r"pip install 'shadowless\[midi\]'"):
                await service.start()
            await service.stop()

    asyncio.run(go())
    (rig_dir / "rig.toml").write_text((rig_dir / "rig.toml").read_text().replace('"MIDI Interface"', "3"))
    with pytest.raises(RigError, match="mtc_port must be"):
        load_osc(rig_dir)


def test_a_port_is_chosen_by_its_name_or_a_part_naming_one():
    names = ["Midi Through:Midi Through Port-0 14:0", "MIDI Interface:MIDI Interface MIDI 1 20:0"]
    assert choose_port("MIDI Interface", names) == names[1]
    assert choose_port(names[0], names) == names[0]
    with pytest.raises(CoordinatorError, match="matches 2 ports"):
        choose_port("midi", names)
    with pytest.raises(CoordinatorError, match="no MIDI input port 'desk'.*--mtc-port list"):
        choose_port("desk", names)


def test_a_real_midi_port_where_the_machine_has_a_midi_system_else_a_one_line_refusal(capfd):
    """One test for both kinds of machine, so it never skips: with an ALSA sequencer, running MTC
    sent through mido's virtual port reaches the chase's callback; without one (a container, this
    project's CI), listing the ports is refused in one line of ours, with no line of ALSA's before it."""
    mido = pytest.importorskip("mido", reason="the midi extra is not installed")
    if sys.platform.startswith("linux") and not os.path.exists(ALSA_SEQ):
        with pytest.raises(MidiUnavailable, match="no MIDI system here: /dev/snd/seq is missing") as e:
            port_names()
        assert "\n" not in str(e.value) and capfd.readouterr().err == "", "no line of ALSA's own before ours"
        return
    mido.set_backend("mido.backends.rtmidi", load=True)
    out = mido.open_output("shadowless-mtc-test", virtual=True)
    got: list = []
    port = MtcInput("shadowless-mtc-test", lambda name, rs: got.extend(rs), lambda: 0)
    try:
        port.open()
        tc = Timecode(1, 2, 3, 4, 3)
        for k in range(8):
            out.send(mido.Message.from_bytes(list(quarter_frames(tc)[2 * k:2 * k + 2])))
        wait_until(lambda: [r.timecode for r in got], what="one timecode read from the virtual port")
        assert [r.timecode for r in got] == [tc]
    finally:
        port.close()
        out.close()
