"""The blend job in the virtual room (in-process, through shadowless.room_driver.RoomDriver): a table
rig with the issue's brightness and white-point spread, hot spot and vignetting, and the 3x1 wall
that only partly overlaps. Flat white becomes even, seams vanish, what was stored is what the nodes
show, captures of the blended rig against the same rig with the maps removed; refusals and the
earlier blend put back on failure."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import points_doc
from coordinator.blend_store import load_blend, load_contributions
from coordinator.blending.geometry_check import slot_digests
from coordinator.jobs import JobError
from imaging.blending.contributions import Contributions
from imaging.blending.metrics import uniformity
from imaging.blending.solve import compute_blend
from protos.blend import BlendMaps
from shadowless.room_driver import RoomDriver
from sim.photometry import Photometry
from sim.rigs import wall_scene
from sim.room import Room
from sim.scene import reference_scene

UNEVEN = Photometry(brightness_spread=0.15, white_spread=0.15, hotspot=0.2, vignetting=0.3)
SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]


def run(driver: RoomDriver, kind: str, params: dict) -> dict:
    return asyncio.run(driver.run(kind, params))


def calibrated(room: Room, path, slots) -> tuple[RoomDriver, object]:
    rig = make_rig(path, room, slots, content_size=(300, 150))
    driver = RoomDriver(room, rig)
    run(driver, "calibrate", {"mode": "multiplexed", "settle_s": 0.0,
                              "table_points": points_doc(table_points_from_truth(room))})
    return driver, rig


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125, photometry=UNEVEN), seed=1)
    driver, rig = calibrated(room, tmp_path_factory.mktemp("blend") / "rig", SLOTS)
    run(driver, "response", {"settle_s": 0.0})
    return room, rig, driver


def flat_white(room: Room, driver: RoomDriver, rig) -> np.ndarray:
    """A capture of flat white content as the nodes show it now, minus black (both averaged over 4)."""
    cw, ch = rig.config.content_width, rig.config.content_height
    driver.render_content(np.ones((ch, cw), np.float32))
    white = np.mean([room.capture(0) for _ in range(4)], axis=0)
    driver.render_content(None)
    black = np.mean([room.capture(0) for _ in range(4)], axis=0)
    return white - black


def test_the_blend_evens_the_table_and_the_nodes_show_what_was_stored(table):
    room, rig, driver = table
    c0 = driver.captures
    out = run(driver, "blend", {"settle_s": 0.0})
    # a flat white before and after, black and one blob capture for four projectors
    assert out["captures"] == driver.captures - c0 == 4 and out["blob_captures"] == 2
    assert out["uniformity_before"] > 0.05
    assert out["uniformity_after"] < 0.03 and out["uniformity_after"] < out["uniformity_before"] / 3
    assert out["uniformity_predicted"] < 0.01
    assert all(v < 0.04 for v in out["colour_after"])
    # auto headroom on a four-fold overlap: about a quarter held back, and what it costs is said
    assert 0.15 < out["headroom"] < 0.45 and 0.15 < out["brightness_cost"] < 0.45 and out["headroom_mode"] == "auto"
    stored = load_blend(rig.path)
    assert stored is not None and sorted(stored.maps) == sorted(SLOTS)
    for s in SLOTS:
        assert isinstance(rig.slot(s).blend, BlendMaps) and rig.slot(s).blend.blend_id == stored.maps[s].blend_id
        assert stored.maps[s].size == (40, 25)            # the room's 160 x 100 projectors at map_scale 4
    for key in ("headroom", "brightness_cost", "uniformity_before", "uniformity_after", "captures", "created_at"):
        assert stored.info[key] == out[key]
    assert set(stored.pictures) == {"before", "after"}
    assert stored.info["slot_digests"] == slot_digests(rig, SLOTS), "what the measurement depended on, per slot"
    contributions = Contributions.from_arrays(*load_contributions(rig.path))
    assert contributions.slots == SLOTS
    sol = compute_blend(contributions)          # what a failover recomputes from the store: the same maps
    for s in SLOTS:
        assert np.allclose(sol.maps[s][0], stored.maps[s].alpha, atol=2e-3)

    # the captures tell: the blended rig against the same rig with its maps removed
    blended = flat_white(room, driver, rig)
    for s in SLOTS:
        rig.update_slot(s, blend=None)
    plain = flat_white(room, driver, rig)
    u_blended = uniformity(blended, sol.target, sol.covered, block=8)
    u_plain = uniformity(plain, sol.target, sol.covered, block=8)
    assert u_blended < 0.02 and u_plain > 3 * u_blended, (u_blended, u_plain)
    for s in SLOTS:
        rig.update_slot(s, blend=stored.maps[s])


def test_a_fixed_headroom_and_refusals(table, tmp_path):
    room, rig, driver = table
    out = run(driver, "blend", {"settle_s": 0.0, "headroom": 0.1, "map_scale": 2})
    assert out["headroom"] == 0.1 and out["headroom_mode"] == "0.1" and 0.08 < out["brightness_cost"] < 0.12
    assert rig.slot(SLOTS[0]).blend.size == (80, 50)
    for bad in (1.5, -0.1, "half"):
        with pytest.raises(JobError, match="headroom must be 'auto' or a number in 0..0.9") as info:
            run(driver, "blend", {"headroom": bad})
        assert "\n" not in str(info.value)
    # no LUTs yet: the blend works in linear light
    fresh, _ = calibrated(room, tmp_path / "fresh", SLOTS[:2])
    with pytest.raises(JobError, match="no inverse-response LUT: .*run `shadowless response` first"):
        run(fresh, "blend", {})


def test_a_failed_run_puts_the_earlier_blend_back(table):
    room, rig, driver = table
    before = {s: rig.slot(s).blend for s in SLOTS}
    assert all(b is not None for b in before.values())
    with pytest.raises(JobError, match="blob radius"):
        run(driver, "blend", {"settle_s": 0.0, "blob_radius": 150.0, "blob_spacing": 400.0})
    assert {s: rig.slot(s).blend for s in SLOTS} == before
    assert load_blend(rig.path).maps[SLOTS[0]].blend_id == before[SLOTS[0]].blend_id


def test_the_partly_overlapping_wall_loses_its_seams(tmp_path):
    room = Room(wall_scene(3, 0.2, projector_scale=0.125, camera_scale=0.125, photometry=UNEVEN), seed=1)
    driver, rig = calibrated(room, tmp_path / "wall", room.slots)
    run(driver, "response", {"settle_s": 0.0})
    out = run(driver, "blend", {"settle_s": 0.0})
    # (the captures as seen, black included: a unit's own black ends at its frame's edge, a step of a
    # fraction of a percent the others' beta maps can only approach)
    assert out["seam_before"] > 0.2 and out["seam_after"] < 0.015, out
    assert out["uniformity_before"] > 0.3 and out["uniformity_after"] < 0.02, out
    # the outer projectors are alone on most of their footprint: a loss there is not covered
    assert out["uncovered"]["r0c0"] > 0.5 and out["uncovered"]["r0c2"] > 0.5 and out["uncovered"]["r0c1"] < 0.7


def test_a_mesh_rig_is_blended_only_when_asked_for(tmp_path):
    from bench.compensation_bust import make_bust_rig
    from sim.rigs import bust_walls_scene

    room = Room(bust_walls_scene(3, projector_scale=0.125, camera_scale=0.125), seed=1)
    rig = make_bust_rig(tmp_path / "bust", room, room.slots, luts=True)
    driver = RoomDriver(room, rig)
    c0 = driver.captures
    with pytest.raises(JobError, match="have a 3D pose: .*experimental") as info:
        run(driver, "blend", {})
    assert "\n" not in str(info.value) and driver.captures == c0
