"""Failover and the watchdog through real processes: node processes render with their blend maps and
send what they show to the virtual room's service (which shows black for a node whose stream ended, as a
projector without signal does), the coordinator runs in this process (so the test reads its node
sessions), and captures come from the room's camera. Four projectors of the table, blended from the
room's true contributions.

1. A node killed: the coordinator declares it lost, the three others switch to new maps at one swap
   instant (their heartbeats name the new maps and the same first-frame pts; a node that heard of them only
   after that instant, on a loaded machine, from its next swap, as its log says), BlendStatus says failover,
   and the capture in the lost footprint is brighter than with the old maps (with the lost projector
   dark) and close to the full blend's.
2. The node restarted: the maps switch back the same way, and the capture is the full blend's again.
3. A coordinator restarted with the watchdog on, a lamp at half in the room: the lamp is named with its
   gain, the rig re-blended, and the capture in its footprint comes back toward the full blend's.
"""
from __future__ import annotations

import asyncio
import re
import signal

import numpy as np

from coordinator.blend_store import StoredBlend, save_blend, save_contributions
from coordinator.blending.failover import BLACK_MAPS
from coordinator.rig import Content, HomographyPose, Rig
from imaging.blending.contributions import luma
from imaging.blending.solve import compute_blend
from imaging.blending.watchdog import grid_mean
from protos.blend import BlendMaps
from shadowless.local import LocalRig
from sim.link import RoomClient
from sim.room import Room
from sim.scene import reference_scene
from sim.wire.service import RoomServerThread
from room_light import truth_contributions
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]
CONTENT = (200, 100)
LEVEL = 0.9


def prepare(rig_dir, room: Room, camera: str, *, watchdog: bool):
    """Poses and LUTs from the room's truth, a stored blend and its contributions, the [blend] section."""
    from bench.uniformity_room import truth_luts

    toml = rig_dir / "rig.toml"
    text = toml.read_text().replace("cameras = []", f'cameras = ["{camera}"]')
    # a lead long enough that every node of a loaded test machine hears of a switch before its instant
    # (the automatic lead suits nodes with CPUs of their own): the common instant is what is tested here
    toml.write_text(text + f"\n[blend]\nwatchdog = {'true' if watchdog else 'false'}\nwatchdog_interval_s = 1.0\n"
                           "switch_lead_ms = 300\n")
    rig = Rig(rig_dir)
    luts = truth_luts(room, SLOTS)
    for s in SLOTS:
        rig.update_slot(s, pose=HomographyPose(room.truth.content_to_projector_homography(s, CONTENT)), lut=luts[s])
    rig.set_content(Content(np.full((CONTENT[1], CONTENT[0], 3), LEVEL, np.float32), name="grey"))
    c = truth_contributions(room, SLOTS)
    sol = compute_blend(c, map_scale=1)
    maps = {s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()}
    save_contributions(rig_dir, *c.to_arrays())
    save_blend(rig_dir, StoredBlend(maps, {"headroom": sol.headroom, "brightness_cost": sol.brightness_cost}))
    return c, maps


def late_reason(node_log: str, blend_id: str, at: int) -> str:
    """Why a node showed maps ``blend_id`` (due at rig instant ``at``) after that instant, from its log
    line of their first swap (node/blend_switch.py): its presenter read them after the instant, or
    rendering the frame again with them took longer than their lead; "" when the log gives no reason."""
    for m in re.finditer(r"blend (\S+) on screen from rig instant (\d+); timing instant=(\d+) received=\d+ "
                         r"decoded=\d+ presenter=(\d+)", node_log):
        if m.group(1) == blend_id and int(m.group(3)) == at:
            if int(m.group(4)) > at:
                return "read after the instant"
    if f"blend {blend_id} shown" in node_log and "after its instant" in node_log:
        return "rendered too slowly for the instant"
    return ""


def set_watchdog(rig_dir, on: bool) -> None:
    toml = rig_dir / "rig.toml"
    toml.write_text(toml.read_text().replace(f"watchdog = {'false' if on else 'true'}", f"watchdog = {'true' if on else 'false'}"))


def test_a_killed_node_is_covered_by_the_others_and_a_dimmed_lamp_is_named(tmp_path):
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=5)
    room.set_active(SLOTS)
    with RoomServerThread(room, no_signal="black") as server, RoomClient(server.address) as eye:
        local = LocalRig(SLOTS, tmp_path, output_size=room.projector_size(SLOTS[0]), content_size=CONTENT,
                         node_output=f"room://{server.address}", mdns=False, latency_ms=250).create()
        contributions, stored = prepare(local.rig_dir, room, f"room://{server.address}", watchdog=False)
        shape = contributions.shape

        def shot() -> np.ndarray:
            """One capture's luminance on the contributions' grid."""
            return luma(grid_mean(np.asarray(eye.capture(0).image, np.float32), shape))

        async def capture() -> np.ndarray:
            """What the room shows once it stopped changing: captures are taken until two in a row agree
            within 1 % (median over the lit blocks), and those two averaged (in worker threads: the
            coordinator shares this event loop)."""
            seen: list[np.ndarray] = [await asyncio.to_thread(shot)]

            async def again():
                seen.append(await asyncio.to_thread(shot))
                a, b = (grid_mean(x[:, :, None], (shape[0] // 8, shape[1] // 8))[:, :, 0] for x in seen[-2:])
                lit = a > 0.2 * a.max()       # 8x8-cell block means: the camera's noise averages out
                return float(np.median(np.abs(b[lit] / a[lit] - 1.0)))

            await wait_until_async(again, lambda change: change < 0.01, what="the room's picture settled")
            return 0.5 * (seen[-2] + seen[-1])

        async def switched(coord, slots, what, *, common: bool = True):
            """Every slot's node shows the still with the maps its slot holds (``common``: all from one
            pts); the last of those pts."""
            def seen():
                out = {}
                for s in slots:
                    sess = coord.by_slot.get(s)
                    ok = sess is not None and not sess.closed and sess.last_swap_frame in sess.still_frames
                    out[s] = (sess.blend_id, sess.blend_since_rig_ns) if ok else ("", 0)
                return out
            got = await wait_until_async(seen, lambda b: all(b[s][0] == coord.rig.slot(s).blend.blend_id
                                                             for s in slots), what=what)
            if common:
                # every node from the switch's instant; one that heard of the maps only after it (a loaded
                # machine) from its next swap, never before the instant, and its log says why
                at = coord.blending.switched_at_ns
                for s, (blend_id, t) in got.items():
                    if t != at:
                        assert t > at and late_reason(local.log(f"node-{s}"), blend_id, at), \
                            ("one common swap instant, or late for a reason", s, t - at, got)
            return max(t for _, t in got.values())

        def served():
            """The coordinator in this event loop, on the port the nodes know."""
            return inprocess_coordinator(Rig(local.rig_dir), local.token, listen=f"127.0.0.1:{local.port}")

        async def phase_one():
            async with served() as app:
                coord = app.coordinator
                for s in SLOTS:
                    local.start_node(s)
                async with await local.client() as c:
                    await local.wait_live(c, timeout=120)
                # blended, once every node is live: a node slower to start than lost_after_ms (a loaded
                # machine) was rightly covered for until its first report, so wait, with a deadline
                await wait_until_async(coord.blend_status, lambda b: b.state == "blended",
                                       what="the stored blend on every projector")
                # each node got the maps as it joined, at once
                await switched(coord, SLOTS, "every node on the stored maps", common=False)
                full = await capture()
                fp = contributions.footprint("r1c1") & (full > 0.3 * full.max())

                # the old maps with r1c1 dark (its lamp off; no watchdog in this rig yet)
                room.set_lamp("r1c1", 0.0)
                old = await capture()
                # r1c1's node killed: declared lost at once (its report stream ends), the others switch
                local.stop_node("r1c1", sig=signal.SIGKILL)
                await wait_until_async(coord.blend_status, lambda b: b.state == "failover" and "r1c1" in b.lost,
                                       what="a failover for r1c1")
                # the status names the loss at once; its maps follow once the variant is ready (computed
                # ahead, or in a worker thread when a loaded machine had not got to it yet)
                await wait_until_async(lambda: coord.rig.slot("r1c1").blend, lambda b: b is BLACK_MAPS,
                                       what="r1c1's projector given black maps")
                others = [s for s in SLOTS if s != "r1c1"]
                at = await switched(coord, others, "the three others on their new maps")
                assert at >= coord.blending.switched_at_ns
                declared = coord.blending.lost_at_ns["r1c1"]
                frames_late = (at - declared) / (1e9 / 60)       # swap periods of a 60 Hz output
                new = await capture()
                st = coord.blend_status()
                assert st.covered and "3 projectors cover its footprint, uniformity kept" in st.message, st
                old_ratio, new_ratio = old[fp] / full[fp], new[fp] / full[fp]
                assert np.median(old_ratio) < 0.85, np.median(old_ratio)
                assert np.median(new_ratio) > np.median(old_ratio) + 0.1, (np.median(old_ratio), np.median(new_ratio))
                assert abs(np.median(new_ratio) - 1.0) < 0.03, np.median(new_ratio)

                # the node comes back: the full blend again, at one instant
                room.set_lamp("r1c1", 1.0)
                local.start_node("r1c1")
                await wait_until_async(coord.blend_status, lambda b: b.state == "blended", what="r1c1 back in the blend")
                assert {s: coord.rig.slot(s).blend.blend_id for s in SLOTS} == {s: m.blend_id for s, m in stored.items()}
                await switched(coord, SLOTS, "every node back on the stored maps")
                back = await capture()
                assert abs(np.median(back[fp] / full[fp]) - 1.0) < 0.02
                return full, frames_late

        async def phase_two(full):
            # a lamp at half while the coordinator is down: the nodes play on with the full blend's maps
            room.set_lamp("r3c3", 0.5)
            set_watchdog(local.rig_dir, True)
            dimmed = await capture()
            async with served() as app:
                coord = app.coordinator
                st = await wait_until_async(coord.blend_status, lambda b: b.lamps, what="the watchdog naming a lamp")
                assert [s for s, _ in st.lamps] == ["r3c3"] and abs(st.lamps[0][1] - 0.5) <= 0.05, st
                await wait_until_async(lambda: coord.blending.applied == coord.blending.wanted_key(), bool,
                                       what="the re-blend computed and switched to")
                assert "lamp of r3c3 at" in coord.blend_status().message
                # (a node that rejoined after a restart gets them at once: no common instant asked here)
                await switched(coord, SLOTS, "every node on the re-blended maps", common=False)
                reblended = await capture()
                fp = contributions.footprint("r3c3") & (full > 0.3 * full.max())
                before = np.abs(dimmed[fp] / full[fp] - 1.0).mean()
                after = np.abs(reblended[fp] / full[fp] - 1.0).mean()
                assert after < 0.5 * before, (before, after)

        try:
            full, frames_late = asyncio.run(phase_one())
            assert frames_late >= 0
            asyncio.run(phase_two(full))
        finally:
            local.close()
