"""The photometric watchdog against the virtual room's lamp truth, in process: the 5x5 table rig (every
projector reaches almost all of it, the hard case), blended from the room's true contributions, shows a
flat grey through the nodes' own pipeline (shadowless.room_driver); lamps are dimmed and killed in the
room (Room.set_lamp) while the nodes stay live. The watchdog names each lamp with its gain within 5 %
of the truth, the rig is re-blended, and the capture in the dimmed footprint comes back to the full
blend's light (compared captures, not flags); a lamp that comes back is forgotten."""
from __future__ import annotations

import asyncio
import logging

import numpy as np
import pytest

from bench.calibration import make_rig
from bench.uniformity_room import truth_luts
from coordinator.blend_store import StoredBlend, save_blend, save_contributions
from coordinator.blending.state import BlendState
from coordinator.blending.watchdog import LampWatchdog
from coordinator.rig import HomographyPose, Rig
from imaging.blending.contributions import luma
from imaging.blending.solve import compute_blend
from imaging.blending.watchdog import grid_mean
from protos.blend import BlendMaps
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import SUBSETS, reference_scene
from room_light import truth_contributions

CONTENT = (300, 150)
LEVEL = 0.9


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=1)
    slots = list(SUBSETS["P25"])
    path = tmp_path_factory.mktemp("watchdog") / "rig"
    rig = make_rig(path, room, slots, content_size=CONTENT)
    luts = truth_luts(room, slots)
    for s in slots:
        rig.update_slot(s, pose=HomographyPose(room.truth.content_to_projector_homography(s, CONTENT)), lut=luts[s])
    c = truth_contributions(room, slots)
    sol = compute_blend(c, map_scale=1)
    save_contributions(path, *c.to_arrays())
    save_blend(path, StoredBlend({s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()},
                                 {"headroom": sol.headroom, "brightness_cost": sol.brightness_cost}))
    return room, Rig(path), c, slots


def test_dimmed_and_dead_lamps_are_named_and_the_rig_re_blended(table, caplog):
    room, rig, c, slots = table
    driver = RoomDriver(room, rig)
    content = np.full((CONTENT[1], CONTENT[0], 3), LEVEL, np.float32)
    now = [10_000_000_000]

    def light() -> np.ndarray:
        """The camera's luminance on the contributions' grid, the mean of 4 captures of what the rig shows."""
        driver.render_content(content)
        return luma(np.mean([grid_mean(room.capture(0), c.shape) for _ in range(4)], axis=0))

    async def go():
        # no variants computed ahead (budget 0): each re-blend is computed when the watchdog asks for it
        state = BlendState(rig, update_slot=rig.update_slot, clock_ns=lambda: now[0], lead_ns=50_000_000,
                           budget_bytes=0)
        state.load()
        watchdog = LampWatchdog(state, camera_specs=driver.camera_specs.copy, busy=lambda: None,
                                on_screen=lambda: (content, 0), live_slots=lambda: slots, interval_s=1.0,
                                clock_ns=lambda: now[0], open_camera=driver.open_camera)

        async def check():
            now[0] += 1_000_000_000          # past any switch's instant and its settling
            driver.render_content(content)  # what the nodes show now
            result = await watchdog.check()
            await state.settled()
            return result

        full = light()
        first = await check()
        assert not first.skipped and first.named == {} and state.lamp_gains == {}, first
        assert first.condition > 1000          # 25 gains from one capture: the full design is ill-conditioned

        caplog.set_level(logging.INFO)
        room.set_lamp("r2c2", 0.5)
        dimmed = light()
        fp = c.footprint("r2c2") & (full > 0.2 * full.max())
        result = await check()
        assert set(result.named) == {"r2c2"} and abs(result.named["r2c2"] - 0.5) <= 0.05, result
        assert abs(state.status().lamps[0][1] - 0.5) <= 0.05 and state.status().state == "failover"
        assert any("lamp of r2c2 at" in r.getMessage() for r in caplog.records)
        assert rig.slot("r1c1").blend.blend_id != state.stored.maps["r1c1"].blend_id, "re-blended"
        reblended = light()
        before = np.abs(dimmed[fp] / full[fp] - 1.0).mean()
        after = np.abs(reblended[fp] / full[fp] - 1.0).mean()
        assert after < 0.5 * before, (before, after)
        again = await check()                 # a second look finds nothing new
        assert again.named == {"r2c2": result.named["r2c2"]}

        room.set_lamp("r4c4", 0.0)
        dead = await check()
        assert dead.named.get("r4c4", 1.0) <= 0.05 and abs(dead.named["r2c2"] - 0.5) <= 0.05, dead
        st = state.status()
        assert "r4c4" in st.lost and "lamp of r4c4 dead" in st.message, st
        assert rig.slot("r4c4").blend.blend_id == state.stored.maps["r4c4"].blend_id   # it keeps its maps

        for s in ("r2c2", "r4c4"):
            room.set_lamp(s, 1.0)
        back = await check()
        assert back.named == {} and state.status().state == "blended", back
        assert {s: rig.slot(s).blend.blend_id for s in slots} == {s: m.blend_id for s, m in state.stored.maps.items()}
        state.close()

    asyncio.run(go())


def test_the_watchdog_is_off_without_a_camera_and_waits_while_a_job_holds_it(table):
    room, rig, c, slots = table
    driver = RoomDriver(room, rig)
    content = np.full((CONTENT[1], CONTENT[0], 3), LEVEL, np.float32)
    captures = driver.captures

    async def go():
        state = BlendState(rig, update_slot=rig.update_slot, clock_ns=lambda: 10**12, lead_ns=0, budget_bytes=0)
        state.load()

        def dog(**kw):
            args = dict(camera_specs=driver.camera_specs.copy, busy=lambda: None, on_screen=lambda: (content, 0),
                        live_slots=lambda: slots, interval_s=1.0, clock_ns=lambda: 10**12,
                        open_camera=driver.open_camera)
            return LampWatchdog(state, **{**args, **kw})

        assert (await dog(camera_specs=list).check()).skipped == "off: the rig has no camera"
        assert (await dog(busy=lambda: "calibrate").check()).skipped == "a calibrate job holds the camera"
        assert (await dog(on_screen=lambda: None).check()).skipped == "no still shown through the poses"
        waiting = await dog(live_slots=lambda: slots[1:]).check()
        assert waiting.skipped == f"waiting for the node of {slots[0]}"
        assert driver.captures == captures, "no capture was taken"
        assert not (await dog().check()).skipped and driver.captures > captures
        state.close()

    asyncio.run(go())
