"""Failover in the coordinator's core, driven through its own methods (what the edges call), with a
stored blend of a synthetic rig whose light is known exactly: the slots get the stored maps when the
rig opens, a lost node switches the others to maps computed ahead (in the same call, with one common
instant a latency budget ahead), the light those maps make in the lost footprint is checked against
the full blend's through the forward model, the node's return switches back, several losses and no
projector left are handled, and a bad [blend] section is one line."""
from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import numpy as np
import pytest

from coordinator.blend_store import StoredBlend, save_blend, save_contributions
from coordinator.blending import blend_job
from coordinator.api import Space
from coordinator.blending.failover import BLACK_MAPS, variant_key
from coordinator.errors import RigError
from coordinator.jobs.options import parse_options
from coordinator.rig import Content, Rig, grid_slots, init_rig
from coordinator.server import Coordinator
from coordinator.sessions import NodeInfo, Report, Swaps
from imaging.blending.contributions import luma
from imaging.blending.predict import predict
from imaging.blending.solve import compute_blend
from imaging.blending.synthetic import rectangle_rig, tiled_rects, wall_rects
from protos.blend import BlendMaps
from waits import wait_until_async

TOKEN = b"f" * 32
CAMERA = (320, 240)
PROJECTOR = (160, 90)


class Packets:
    """A packet encoding that sends nothing anyone reads."""

    def encoder(self) -> "Packets":
        return self

    def prepare(self, contents) -> None:
        pass

    def packet(self, *, frame=None, contents=(), evict=(), video=None) -> bytes:
        return b""


def blended_rig(tmp_path: Path, slots: list[str], rects, *, toml_extra: str = "") -> tuple[Rig, object, dict]:
    """A rig of ``slots`` with a stored blend of the synthetic rig ``rects`` (its contributions too)."""
    path = init_rig(tmp_path / "rig", name="blended", slots=slots, width=PROJECTOR[0], height=PROJECTOR[1],
                    content_width=64, content_height=48, latency_ms=40)
    if toml_extra:
        (path / "rig.toml").write_text((path / "rig.toml").read_text() + toml_extra)
    peaks = np.random.default_rng(3).uniform(0.85, 1.15, len(slots))
    c = rectangle_rig(rects, camera_size=CAMERA, scale=4, projector_size=PROJECTOR, peaks=peaks, names=slots)
    sol = compute_blend(c, map_scale=1)     # map texels finer than the camera grid, as on a real rig
    maps = {s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()}
    save_contributions(path, *c.to_arrays())
    save_blend(path, StoredBlend(maps, {"headroom": sol.headroom, "brightness_cost": sol.brightness_cost,
                                        "created_at": 1.0e9}))
    return Rig(path), c, maps


def white_of(c, maps: dict[str, BlendMaps], lost=()) -> np.ndarray:
    """Luminance above black on the camera grid when every projector shows white with ``maps`` (a
    projector without maps shows white unblended; ``lost`` ones nothing)."""
    pairs = {s: (m.alpha, m.beta) for s, m in maps.items()}
    return luma(predict(c, pairs, 1.0, lost=tuple(lost)) - predict(c, pairs, 0.0, lost=tuple(lost)))


def test_a_lost_node_switches_the_others_at_one_instant_and_its_return_switches_back(tmp_path, caplog):
    slots = grid_slots(2, 2)
    rig, contributions, stored = blended_rig(tmp_path, slots, tiled_rects(2, 2, CAMERA, seed=2))
    now = [7_000_000_000]

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets, clock_ns=lambda: now[0])
        coord.open()
        try:
            # the stored maps are on the slots as soon as the rig opens
            assert {s: rig.slot(s).blend.blend_id for s in slots} == {s: stored[s].blend_id for s in slots}
            st = coord.blend_status()
            assert st.state == "blended" and st.blend_id and "headroom" in st.message, st
            coord.start()
            await coord.blending.variants.wait_ahead()     # the single losses, computed in a worker thread
            assert all(coord.blending.variants.get(variant_key({s})) for s in slots)
            sessions = {s: coord.join(slot=s, info=NodeInfo(hostname=f"pi-{s}", pid=i + 1), peer=f"ipv4:10.0.0.{i}:1")
                        for i, s in enumerate(slots)}
            for sess in sessions.values():
                coord.on_report(sess, Report())            # live
            revisions = {s: rig.slot(s).revision for s in slots}

            caplog.set_level(logging.INFO)
            coord.mark_lost(sessions["r0c1"])
            # in the same call, every slot switched, the same instant a switch lead ahead
            after = {s: rig.slot(s) for s in slots}
            assert all(after[s].revision == revisions[s] + 1 for s in slots)
            assert {after[s].blend_at_ns for s in slots} == {now[0] + coord.blending.last_lead_ns}
            assert after["r0c1"].blend is BLACK_MAPS
            assert all(after[s].blend.blend_id != stored[s].blend_id for s in slots if s != "r0c1")
            assert [r.getMessage().split(" from rig")[0] for r in caplog.records if "take over" in r.getMessage()] == \
                ["blend: r0c1 lost; 3 projectors take over with new maps"], "one line per switch"
            st = coord.blend_status()
            assert st.state == "failover" and st.lost == ("r0c1",) and st.covered, st
            assert st.message.startswith("r0c1 lost 0 s ago: 3 projectors cover its footprint, uniformity kept"), st

            # the light: with the old maps the lost footprint is dark by the lost share; with the new
            # ones it is the full blend's, within 2 % (p1..p99), over the footprint the others reach
            full = white_of(contributions, stored)
            new = {s: after[s].blend for s in slots if s != "r0c1"}
            fp = contributions.footprint("r0c1") & (full > 0.05 * full.max())
            old_ratio = white_of(contributions, stored, lost=("r0c1",))[fp] / full[fp]
            new_ratio = white_of(contributions, new, lost=("r0c1",))[fp] / full[fp]
            assert np.median(old_ratio) < 0.85, np.median(old_ratio)
            assert np.percentile(new_ratio, 1) > 0.97 and np.percentile(new_ratio, 99) < 1.03, \
                np.percentile(new_ratio, [1, 50, 99])

            # the node returns while a still is on screen (a new session turns live): the full blend
            # again once it swaps a frame, at one instant
            coord.show(coord.prepare_still(Content(np.full((48, 64, 3), 200, np.uint8)), Space.CONTENT),
                       space=Space.CONTENT, apply_lut=True)
            now[0] += 2_000_000_000
            back = coord.join(slot="r0c1", info=NodeInfo(hostname="pi-r0c1", pid=99), peer="ipv4:10.0.0.1:2")
            assert rig.slot("r0c1").blend is BLACK_MAPS        # it joins dark
            coord.on_report(back, Report())
            assert rig.slot("r0c1").blend is BLACK_MAPS        # live, but the still not on its screen yet
            coord.on_report(back, Report(swaps=Swaps.of([(1, now[0], now[0])])))
            assert {s: rig.slot(s).blend.blend_id for s in slots} == {s: stored[s].blend_id for s in slots}
            assert {rig.slot(s).blend_at_ns for s in slots} == {now[0] + coord.blending.last_lead_ns}
            assert coord.blend_status().state == "blended"

            # two lost at once: computed on demand in a worker thread, then switched
            coord.mark_lost(sessions["r0c0"])
            coord.mark_lost(back)
            await coord.blending.settled()
            st = coord.blend_status()
            assert st.lost == ("r0c0", "r0c1") and st.state == "failover", st
            assert rig.slot("r0c0").blend is BLACK_MAPS and rig.slot("r0c1").blend is BLACK_MAPS
            assert rig.slot("r1c0").blend.blend_id not in {stored["r1c0"].blend_id}

            # no projector left: reported, not crashed on, and the maps stay as they were
            held = {s: rig.slot(s).blend for s in slots}
            for s in ("r1c0", "r1c1"):
                coord.mark_lost(sessions[s])
            await coord.blending.settled()
            st = coord.blend_status()
            assert st.state == "failover" and not st.covered and "cannot re-blend" in st.message \
                and "no projector left" in st.message, st
            assert {s: rig.slot(s).blend for s in slots} == held
        finally:
            await coord.close()

    asyncio.run(go())


def test_a_footprint_the_others_do_not_reach_is_reported(tmp_path):
    slots = ["left", "mid", "right"]
    rig, contributions, stored = blended_rig(tmp_path, slots, wall_rects(3, 0.2, CAMERA))
    now = [1_000_000_000]

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets, clock_ns=lambda: now[0])
        coord.open()
        try:
            coord.start()
            sess = coord.join(slot="mid", info=NodeInfo(hostname="pi", pid=1), peer="ipv4:10.0.0.9:1")
            coord.on_report(sess, Report())
            coord.mark_lost(sess)
            await coord.blending.settled()
            st = coord.blend_status()
            assert st.state == "failover" and not st.covered, st
            assert "2 projectors cover" in st.message and "of its footprint" in st.message, st
            # the neighbours still light their share of the seams brighter than before
            full = white_of(contributions, stored)
            new = {s: rig.slot(s).blend for s in ("left", "right")}
            seam = contributions.footprint("mid") & (contributions.footprint("left") | contributions.footprint("right"))
            seam &= full > 0.05 * full.max()
            assert np.median(white_of(contributions, new, lost=("mid",))[seam] / full[seam]) > \
                np.median(white_of(contributions, stored, lost=("mid",))[seam] / full[seam]) + 0.2
            # back with nothing on screen: no frame to wait for, so the full blend at its first report
            back = coord.join(slot="mid", info=NodeInfo(hostname="pi", pid=2), peer="ipv4:10.0.0.9:2")
            assert coord.blend_status().state == "failover"
            coord.on_report(back, Report())
            assert coord.blend_status().state == "blended", coord.blend_status()
            assert {s: rig.slot(s).blend.blend_id for s in slots} == {s: stored[s].blend_id for s in slots}
        finally:
            await coord.close()

    asyncio.run(go())


@pytest.mark.parametrize("value", ["1.2", "-0.1", '"most"', "true"])
def test_a_headroom_outside_0_to_0_9_is_one_line_and_changes_nothing(tmp_path, value):
    path = init_rig(tmp_path / "rig", name="bad", slots=["a"], width=32, height=32)
    good = (path / "rig.toml").read_text()
    (path / "rig.toml").write_text(good + f"\n[blend]\nheadroom = {value}\n")
    before = sorted(p.name for p in path.rglob("*"))
    with pytest.raises(RigError) as err:
        Rig(path)
    msg = str(err.value)
    assert "\n" not in msg and "rig.toml" in msg and "headroom" in msg and "0..0.9" in msg, msg
    assert sorted(p.name for p in path.rglob("*")) == before
    # the good values read
    for ok, want in (('"auto"', None), ("0.25", 0.25), ("0", 0.0)):
        (path / "rig.toml").write_text(good + f"\n[blend]\nheadroom = {ok}\nwatchdog = false\nwatchdog_interval_s = 5\n")
        cfg = Rig(path).config.blend
        assert (cfg.headroom, cfg.watchdog, cfg.watchdog_interval_s) == (want, False, 5.0)
        # the blend job takes it when a request sets no headroom
        defaults, source = blend_job.option_defaults(Rig(path))
        opts = parse_options(blend_job.OPTIONS, {}, what="blend", defaults=defaults, defaults_source=source)
        assert opts.headroom == ("auto" if want is None else want)
        assert parse_options(blend_job.OPTIONS, {"headroom": 0.5}, what="blend", defaults=defaults,
                             defaults_source=source).headroom == 0.5


def test_a_projector_whose_node_never_joins_is_covered_once_it_would_count_as_lost(tmp_path):
    slots = grid_slots(2, 2)
    rig, contributions, stored = blended_rig(tmp_path, slots, tiled_rects(2, 2, CAMERA, seed=2))
    now = [3_000_000_000]

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets, clock_ns=lambda: now[0])
        coord.open()
        try:
            coord.start()
            sessions = [coord.join(slot=s, info=NodeInfo(hostname=f"pi-{s}", pid=i + 1), peer=f"ipv4:10.0.0.{i}:1")
                        for i, s in enumerate(slots[1:])]
            coord.sweep()
            assert coord.blend_status().state == "blended"      # r0c0's node may still be starting
            now[0] += rig.config.lost_after_ms * 1_000_000 + 1
            for sess in sessions:
                sess.last_seen = coord.now()
            coord.sweep()
            await coord.blending.settled()
            st = coord.blend_status()
            assert st.state == "failover" and st.lost == ("r0c0",), st
            assert rig.slot("r0c0").blend is BLACK_MAPS and rig.slot("r0c1").blend.blend_id != stored["r0c1"].blend_id
        finally:
            await coord.close()

    asyncio.run(go())


def test_a_blend_job_suspends_the_failover_and_its_new_blend_is_taken_when_it_ends(tmp_path):
    slots = grid_slots(2, 2)
    rig, contributions, stored = blended_rig(tmp_path, slots, tiled_rects(2, 2, CAMERA, seed=2))
    now = [3_000_000_000]

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets, clock_ns=lambda: now[0])
        coord.open()
        try:
            coord.start()
            sessions = {s: coord.join(slot=s, info=NodeInfo(hostname=f"pi-{s}", pid=i + 1), peer=f"ipv4:10.0.0.{i}:1")
                        for i, s in enumerate(slots)}
            old_id = coord.blend_status().blend_id
            coord.jobs.begin("blend", {})          # the job clears the maps and measures: nothing is pushed meanwhile
            for s in slots:
                coord.update_slot(s, blend=None, blend_at_ns=0)
            coord.mark_lost(sessions["r1c1"])
            assert all(rig.slot(s).blend is None for s in slots), "no failover push during a blend job"
            # the job stores a new blend (here: the same light, other maps) and sets it
            sol = compute_blend(contributions, map_scale=1, headroom=0.5)
            new = {s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()}
            save_blend(rig.path, StoredBlend(new, {"headroom": 0.5, "brightness_cost": sol.brightness_cost}))
            for s in slots:
                coord.update_slot(s, blend=new[s], blend_at_ns=0)
            coord.jobs.end(result={})
            await wait_until_async(lambda: coord.blend_status(), lambda st: st.blend_id != old_id,
                                   what="the new blend taken")
            await coord.blending.settled()
            st = coord.blend_status()
            assert st.headroom == 0.5 and st.state == "failover" and st.lost == ("r1c1",), st
            assert rig.slot("r1c1").blend is BLACK_MAPS       # the loss during the job is covered now
            assert all(rig.slot(s).blend.blend_id not in (new[s].blend_id, stored[s].blend_id)
                       for s in slots if s != "r1c1")
        finally:
            await coord.close()

    asyncio.run(go())


def test_the_watchdog_sees_a_timeline_show_of_a_still_asset_or_of_a_sequence_of_one_picture(tmp_path):
    import cv2

    rig, _, _ = blended_rig(tmp_path, ["a"], [(20, 20, 300, 220)])
    picture = np.random.default_rng(4).integers(0, 255, (24, 32, 3), np.uint8)      # half the content's size
    cv2.imwrite(str(tmp_path / "card.png"), picture[:, :, ::-1])
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2):
        cv2.imwrite(str(frames / f"{k}.png"), picture[:, :, ::-1])
    changing = tmp_path / "changing"
    changing.mkdir()
    for k in range(2):
        cv2.imwrite(str(changing / f"{k}.png"), (picture // (k + 1))[:, :, ::-1])

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets)
        coord.open()
        try:
            still = coord.asset_store.add(tmp_path / "card.png", name="card")
            seq = coord.asset_store.add(frames, name="frames", fps=10)
            await coord.refresh_assets()
            coord.play_asset("card")
            image, at = coord.still_on_screen()
            assert callable(image) and at == coord.show_state.timeline.anchor_ns
            got = image()
            assert got.shape == (48, 64, 3)
            assert np.abs(got.astype(int) - cv2.resize(picture, (64, 48), interpolation=cv2.INTER_LINEAR)).max() <= 1
            moving = coord.asset_store.add(changing, name="changing", fps=10)
            await coord.refresh_assets()
            # a sequence whose frames are one file shows one picture for as long as the show runs
            coord.play_asset("frames", loop=True)
            image, at, until = coord.still_on_screen()
            assert at == coord.show_state.timeline.anchor_ns and until is None
            assert np.array_equal(image(), got)
            # one whose frames change: each picture for its frame's period only (the watchdog needs longer)
            coord.play_asset("changing", loop=True)
            tl = coord.show_state.timeline
            screen = coord.still_on_screen()
            assert screen is not None and screen[1:] == (tl.anchor_ns, tl.anchor_ns + 100_000_000)
            assert still.kind == "still" and seq.kind == "sequence" and moving.kind == "sequence"
        finally:
            await coord.close()

    asyncio.run(go())


def test_a_blend_says_it_is_stale_once_a_pose_lut_or_gain_changes_after_its_measurement(tmp_path):
    """The blend job stores a digest of each slot's pose, LUT and gain; once one changes (a new
    response run, a gain set by hand, a recalibration), status names the slot and says to measure
    again. A blend stored without digests (older, or imported) is not judged."""
    from coordinator.blend_store import load_blend
    from coordinator.blending.geometry_check import slot_digests
    slots = grid_slots(1, 2)
    rig, _, _ = blended_rig(tmp_path, slots, tiled_rects(1, 2, CAMERA, seed=4))
    stored = load_blend(rig.path)
    save_blend(rig.path, StoredBlend(stored.maps, {**stored.info, "slot_digests": slot_digests(rig, slots)}))

    async def go():
        coord = Coordinator(Rig(rig.path), TOKEN, encoding=Packets)
        coord.open()
        try:
            st = coord.blend_status()
            assert st.state == "blended" and "changed since" not in st.message, st
            coord.rig.update_slot("r0c1", gain=0.8)
            st = coord.blend_status()
            assert st.state == "blended" and "of r0c1 changed since it was measured" in st.message \
                and "shadowless blend" in st.message, st
            coord.rig.update_slot("r0c1", gain=1.0)     # back as measured: nothing to say
            assert "changed since" not in coord.blend_status().message
            # a new LUT (a response run) replaces the array: the status, asked often, sees it at once
            coord.rig.update_slot("r0c0", lut=np.tile(np.linspace(0, 1, 64, dtype=np.float32) ** 1.2, (3, 1)))
            assert "of r0c0 changed since it was measured" in coord.blend_status().message
        finally:
            await coord.close()

    asyncio.run(go())
