"""`shadowless status` on the blend: none (and how to make one), blended (when, the headroom and its
cost), in failover (who, since when, whether uniformity is kept) with the lamps the watchdog named;
as text and as JSON, through the wire, and from the command against a running coordinator."""
from __future__ import annotations

import asyncio
import json
import re
import time

import pytest

import numpy as np

from coordinator.api import BlendStatus, RigStatus
from coordinator.blend_store import StoredBlend, save_blend
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.wire import control_messages
from protos.auth import read_token
from protos.blend import BlendMaps
from rigctl.blend_status import ago, blend_lines
from rigctl.commands import status_dict, status_table
from procs import shadowless_process
from inprocess_coordinator import inprocess_coordinator

NOW = 1_800_000_000.0
BLENDED = BlendStatus(state="blended", blend_id="b1", created_at=NOW - 7200, headroom=0.08, brightness_cost=0.08)
FAILOVER = BlendStatus(state="failover", blend_id="b2", created_at=NOW - 7200, headroom=0.08, brightness_cost=0.0775,
                       lost=("r2c3",), since=NOW - 12, covered=True,
                       message="r2c3 lost 12 s ago: 24 projectors cover its footprint")
LAMPS = BlendStatus(state="failover", blend_id="b3", created_at=NOW - 600, headroom=0.2, brightness_cost=0.2,
                    lost=("r0c0", "r1c1"), since=NOW - 75, covered=False, lamps=(("r0c0", 0.5), ("r1c1", 0.0)))


def text_and_json(b: BlendStatus) -> tuple[list[str], dict]:
    st = control_messages.status_from_message(control_messages.status_message(RigStatus("id", "hall", blend=b)))
    d = status_dict(st, now=NOW)
    return status_table(d).splitlines(), json.loads(json.dumps(d))["blend"]


def test_no_blend_says_how_to_make_one():
    lines, d = text_and_json(BlendStatus())
    blend = [line for line in lines if line.startswith(("blend", "failover", "lamp"))]
    assert blend == ["blend: none (each projector at one gain, no failover): measure one with "
                     "`shadowless blend RIG`"]
    assert d == {"state": "none", "blend_id": "", "created_at": None, "age_s": None, "headroom": 0.0,
                 "brightness_cost": 0.0, "lost": [], "since": None, "lost_for_s": None, "covered": True, "lamps": [],
                 "message": ""}


def test_a_blend_says_when_it_was_measured_and_what_its_headroom_costs():
    lines, d = text_and_json(BLENDED)
    assert "blend: measured 2.0 h ago, headroom 8 % (costs 8 % of brightness)" in lines
    assert not [line for line in lines if line.startswith(("failover", "lamp"))]
    assert (d["state"], d["blend_id"], d["created_at"], d["age_s"]) == ("blended", "b1", NOW - 7200, 7200.0)
    assert (d["headroom"], d["brightness_cost"], d["lost"], d["since"]) == (0.08, 0.08, [], None)


def test_a_note_on_the_blend_and_a_blend_not_in_use_are_said():
    noted = BlendStatus(state="blended", created_at=NOW - 60, headroom=0.1, brightness_cost=0.1,
                        message="blended (measured 1 min ago): headroom 10% held for failover costs 10% of "
                                "brightness; no contributions stored, so no failover")
    lines, _ = text_and_json(noted)
    assert ("blend: measured 60 s ago, headroom 10 % (costs 10 % of brightness); no contributions stored, so no "
            "failover") in lines
    unusable = BlendStatus(message="blend/g000003/info.json: damaged (its checksum differs)")
    lines, d = text_and_json(unusable)
    assert [line for line in lines if line.startswith("blend")] == [
        "blend: none (each projector at one gain, no failover): measure one with `shadowless blend RIG`",
        "blend: blend/g000003/info.json: damaged (its checksum differs)"]
    assert d["message"] == unusable.message


def test_a_failover_is_one_line_with_the_coordinators_count_and_the_verdict():
    lines, d = text_and_json(FAILOVER)
    assert "blend: measured 2.0 h ago, headroom 8 % (costs 7.8 % of brightness)" in lines
    assert "failover: r2c3 lost 12 s ago: 24 projectors cover its footprint, uniformity kept" in lines
    assert d["state"] == "failover" and d["lost"] == ["r2c3"] and d["since"] == NOW - 12
    assert d["lost_for_s"] == 12.0 and d["covered"] is True and d["message"] == FAILOVER.message


def test_lamps_named_by_the_watchdog_and_a_footprint_not_covered():
    lines, d = text_and_json(LAMPS)
    assert ("failover: r0c0, r1c1 lost 75 s ago: the others do not cover all of their footprints, "
            "uniformity NOT kept: part of the lost light has no other projector") in lines
    assert "lamp r0c0 dimmed: estimated gain 0.50 (photometric watchdog)" in lines
    assert "lamp r1c1 dark: estimated gain 0.00 (photometric watchdog)" in lines
    assert d["lamps"] == [{"slot": "r0c0", "gain": 0.5}, {"slot": "r1c1", "gain": 0.0}] and d["covered"] is False


def test_a_dimmed_lamp_still_in_the_blend_is_named_with_its_gain():
    dimmed = BlendStatus(state="failover", created_at=NOW - 60, headroom=0.1, brightness_cost=0.1, since=NOW - 10,
                         covered=True, lamps=(("r1c1", 0.5),))
    lines, d = text_and_json(dimmed)
    assert "failover: lamp of r1c1 at 50 % 10 s ago: the others cover its footprint, uniformity kept" in lines
    assert "lamp r1c1 dimmed: estimated gain 0.50 (photometric watchdog)" in lines and d["lost"] == []


@pytest.mark.parametrize("seconds, said", [(0, "0 s"), (12.4, "12 s"), (89, "89 s"), (90, "2 min"),
                                           (5399, "90 min"), (5400, "1.5 h"), (47 * 3600, "47.0 h"),
                                           (3 * 86400, "3 d"), (-5, "0 s")])
def test_ages_read_as_an_operator_reads_them(seconds, said):
    assert ago(seconds) == said


def test_an_older_coordinator_without_a_blend_reads_as_none():
    msg = control_messages.status_message(RigStatus("id", "hall", blend=FAILOVER))
    msg.ClearField("blend")
    back = control_messages.status_from_message(msg)
    assert back.blend == BlendStatus()
    assert blend_lines(status_dict(back, now=NOW)["blend"])[0].startswith("blend: none")



async def status_both(conn: list[str]) -> tuple[dict, str]:
    """`shadowless status --json` and `shadowless status`, run side by side: the JSON's blend, the text."""
    as_json, as_text = await asyncio.gather(asyncio.to_thread(shadowless_process, "status", "--json", *conn),
                                            asyncio.to_thread(shadowless_process, "status", *conn))
    assert as_json.returncode == 0 and as_text.returncode == 0, (as_json.stderr, as_text.stderr)
    return json.loads(as_json.stdout)["blend"], as_text.stdout


def test_the_status_command_prints_the_coordinators_blend(tmp_path):
    """A running coordinator (no nodes needed) and the real `shadowless status` process: as the core
    reports a rig never blended, then one opened with a stored blend, then in failover (the core's
    blend status set to it: the failover itself is the core's and its tests')."""
    never = Rig(init_rig(tmp_path / "never", name="never", slots=grid_slots(1, 2), width=32, height=32))

    async def never_blended():
        async with inprocess_coordinator(never, read_token(never.path / "token")) as app:
            conn = ["--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", str(never.path)]
            d, text = await status_both(conn)
            assert d["state"] == "none" and "blend: none" in text and "`shadowless blend RIG`" in text, text

    asyncio.run(never_blended())
    path = init_rig(tmp_path / "rig", name="hall", slots=grid_slots(1, 2), width=32, height=32)
    toml = path / "rig.toml"        # no node ever joins: a slow start under load must not count them lost
    toml.write_text(re.sub(r"lost_after_ms = \d+", "lost_after_ms = 3600000", toml.read_text()))
    rig = Rig(path)
    rng = np.random.default_rng(0)
    save_blend(rig.path, StoredBlend({s: BlendMaps(rng.uniform(0.5, 1, (4, 8, 3)).astype(np.float32),
                                                   np.zeros((4, 8), np.float32)) for s in rig.slots},
                                     {"created_at": time.time() - 7300, "headroom": 0.125, "brightness_cost": 0.11}))

    async def go():
        async with inprocess_coordinator(rig, read_token(rig.path / "token")) as app:
            conn = ["--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", str(rig.path)]
            d, text = await status_both(conn)
            assert d["state"] == "blended" and d["headroom"] == 0.125 and d["brightness_cost"] == 0.11, d
            assert 7300 <= d["age_s"] < 7900 and d["lost"] == [] and d["since"] is None, d
            assert ("blend: measured 2.0 h ago, headroom 12 % (costs 11 % of brightness); no contributions stored, "
                    "so no failover") in text.splitlines(), text
            since = time.time() - 30
            failover = BlendStatus(state="failover", blend_id="bb", created_at=since - 3600, headroom=0.1,
                                   brightness_cost=0.1, lost=("r0c1",), since=since, covered=True,
                                   lamps=(("r0c0", 0.52),), message="r0c1 lost: 1 projector covers its footprint")
            app.coordinator.blend_status = lambda: failover
            d, text = await status_both(conn)
            assert d["state"] == "failover" and d["lost"] == ["r0c1"] and d["since"] == pytest.approx(since)
            assert 30 <= d["lost_for_s"] < 600 and d["lamps"] == [{"slot": "r0c0", "gain": 0.52}]
            lines = text.splitlines()
            assert "failover: r0c1 lost: 1 projector covers its footprint, uniformity kept" in lines, text
            assert "lamp r0c0 dimmed: estimated gain 0.52 (photometric watchdog)" in lines
            assert any(line.startswith("blend: measured 6") and line.endswith(" min ago, headroom 10 % (costs 10 % of "
                                                                            "brightness)") for line in lines), text

    asyncio.run(go())
