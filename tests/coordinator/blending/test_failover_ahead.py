"""Failover's switch lead and the maps it holds ahead: rig.toml's ``[blend] switch_lead_ms`` is the
lead of a switch (not the content's latency budget; by default from the bytes the switch pushes) and
a bad one is one line; the single-loss
maps computed ahead are held as their float16 wire encoding, the first ready to push and the rest
compressed within the budget, the likeliest loss first; a loss whose maps are held compressed
switches once they are inflated, to exactly the maps computed directly."""
from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from coordinator.blend_store import StoredBlend, save_blend, save_contributions
from coordinator.blending.failover import BLACK_MAPS, Variants, base_white, compute_variant, variant_key
from coordinator.blending.state import BlendState
from coordinator.errors import RigError
from coordinator.rig import Rig, init_rig
from coordinator.server import Coordinator
from imaging.blending.solve import compute_blend
from imaging.blending.synthetic import rectangle_rig, wall_rects
from protos.blend import BlendMaps

CAMERA = (240, 160)
PROJECTOR = (80, 45)
SLOTS = ["left", "mid", "right"]


class Packets:
    def encoder(self) -> "Packets":
        return self

    def prepare(self, contents) -> None:
        pass

    def packet(self, *, frame=None, contents=(), evict=(), video=None) -> bytes:
        return b""


def blended(tmp_path: Path, toml_extra: str = ""):
    """A rig of three projectors side by side with a stored blend (maps a texel per pixel) and its
    contributions."""
    path = init_rig(tmp_path / "rig", name="ahead", slots=SLOTS, width=PROJECTOR[0], height=PROJECTOR[1],
                    content_width=64, content_height=48, latency_ms=40)
    if toml_extra:
        (path / "rig.toml").write_text((path / "rig.toml").read_text() + toml_extra)
    c = rectangle_rig(wall_rects(3, 0.3, CAMERA), camera_size=CAMERA, scale=4, projector_size=PROJECTOR,
                      peaks=[0.9, 1.1, 1.0], names=SLOTS)
    sol = compute_blend(c, map_scale=1)
    maps = {s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()}
    save_contributions(path, *c.to_arrays())
    save_blend(path, StoredBlend(maps, {"headroom": sol.headroom, "brightness_cost": sol.brightness_cost,
                                        "created_at": 1.0e9}))
    return path, c, maps


@pytest.mark.parametrize("value", ["0", "1500", '"soon"', "true", "nan"])
def test_a_switch_lead_outside_1_to_1000_ms_is_one_line_and_changes_nothing(tmp_path, value):
    path = init_rig(tmp_path / "rig", name="bad", slots=["a"], width=32, height=32)
    good = (path / "rig.toml").read_text()
    (path / "rig.toml").write_text(good + f"\n[blend]\nswitch_lead_ms = {value}\n")
    before = sorted(p.name for p in path.rglob("*"))
    with pytest.raises(RigError) as err:
        Rig(path)
    msg = str(err.value)
    assert "\n" not in msg and "rig.toml" in msg and "switch_lead_ms" in msg and "1..1000" in msg, msg
    assert sorted(p.name for p in path.rglob("*")) == before


def test_the_switch_lead_is_its_own_setting_not_the_latency_budget(tmp_path):
    path = init_rig(tmp_path / "rig", name="lead", slots=["a"], width=32, height=32, latency_ms=80)
    assert Rig(path).config.blend.switch_lead_ms is None          # the default: "auto"
    assert Coordinator(Rig(path), b"t" * 32, encoding=Packets).blending.lead_ns is None
    good = (path / "rig.toml").read_text()
    (path / "rig.toml").write_text(good + "\n[blend]\nswitch_lead_ms = 12.5\n")
    coord = Coordinator(Rig(path), b"t" * 32, encoding=Packets)
    assert coord.latency_ns == 80_000_000 and coord.blending.lead_ns == 12_500_000
    (path / "rig.toml").write_text(good + '\n[blend]\nswitch_lead_ms = "auto"\n')
    assert Rig(path).config.blend.switch_lead_ms is None


def test_losses_ahead_are_held_packed_within_the_budget_and_a_compressed_one_switches_to_the_maps_computed_directly(
        tmp_path):
    path, c, maps = blended(tmp_path)
    rig = Rig(path)
    now = [5_000_000_000]
    texels = PROJECTOR[0] * PROJECTOR[1]
    ready_bytes = 2 * texels * (3 + 1) * 2          # two remaining projectors' alpha and beta as float16
    budget = 2 * ready_bytes                        # one ready; the others only compressed (about 3x smaller)
    pushed = []

    def update_slot(slot, **kw):
        pushed.append(slot)
        return rig.update_slot(slot, **kw)

    async def go():
        state = BlendState(rig, update_slot=update_slot, clock_ns=lambda: now[0], lead_ns=None,
                           budget_bytes=budget)
        state.load()
        # the likeliest loss first (a node lost before in this run), then each other one once
        order = state.variants.order(variant_key(()), {"right": 2})
        assert order[0] == variant_key({"right"}) and len(order) == 3
        assert set(order) == {variant_key({s}) for s in SLOTS}
        state.start()
        await state.variants.wait_ahead()
        counts = state.variants.ahead_counts()
        assert counts == {"planned": 3, "ready": 1, "compressed": 2, "not_held": 0}, counts
        assert state.variants.held_bytes() <= budget
        first = state.variants.planned[0]
        held = {k: state.variants.held(k) for k in state.variants.planned}
        assert held[first].nbytes == ready_bytes + BLACK_MAPS.alpha.nbytes + BLACK_MAPS.beta.nbytes
        assert all(held[k].nbytes < ready_bytes / 2 for k in held if k != first)

        # a loss whose maps are held compressed: switched once inflated in a worker thread
        victim = next(iter(next(k for k in state.variants.planned if k != first)[0]))
        white = base_white(c, maps)
        reference = compute_variant(c, maps, white, variant_key({victim}), map_scale=1)
        pushed.clear()
        state.node_lost(victim)
        await state.settled()
        # the automatic lead: 20 ms and the pushed maps' float16 bytes at 1 Gbit/s (two maps of 80x45
        # texels at 8 bytes each, and the lost slot's black 1x1)
        lead = 20_000_000 + (2 * 80 * 45 * 8 + 8) * 8
        assert sorted(pushed) == SLOTS and {rig.slot(s).blend_at_ns for s in SLOTS} == {now[0] + lead}
        assert rig.slot(victim).blend is BLACK_MAPS
        for s in SLOTS:
            if s != victim:
                got, want = rig.slot(s).blend, reference.maps[s]
                assert got.blend_id == want.blend_id and got.encode() == want.encode()
                np.testing.assert_array_equal(got.alpha, want.alpha.astype(np.float16).astype(np.float32))
        # the loss of the one held ready switches in the same call
        state.node_live(victim)
        await state.settled()
        pushed.clear()
        ready_victim = next(iter(first[0]))
        state.node_lost(ready_victim)
        assert sorted(pushed) == SLOTS and rig.slot(ready_victim).blend is BLACK_MAPS
        state.close()

    asyncio.run(go())


def test_large_maps_fail_over_to_coarser_maps_that_keep_the_light():
    """Maps at least 256 texels wide: a loss's maps are computed four times coarser (a sixteenth of the
    bytes to push) and the light they predict in the lost footprint stays within 1 % of that of maps as
    fine as the full blend's (the reference: the same variant computed at the full blend's scale)."""
    from coordinator.blending.failover import variant_scale
    from imaging.blending.contributions import luma
    from imaging.blending.predict import predict
    camera, projector = (240, 160), (256, 144)
    c = rectangle_rig(wall_rects(3, 0.3, camera), camera_size=camera, scale=4, projector_size=projector,
                      peaks=[0.9, 1.1, 1.0], names=SLOTS)
    maps = {s: BlendMaps(a, b) for s, (a, b) in compute_blend(c, map_scale=1).maps.items()}
    assert variant_scale(maps, c) == 4
    small = {s: BlendMaps(a[::4, ::4], b[::4, ::4]) for s, (a, b) in ((s, (m.alpha, m.beta)) for s, m in maps.items())}
    assert variant_scale(small, c) == 4, "maps under 256 texels wide: at the full blend's own scale (256 / 64)"
    grid = c.white["left"].shape[:2]
    mesh = dataclasses.replace(c, projector_xy={s: np.full((*grid, 2), np.nan, np.float32) for s in SLOTS})
    assert variant_scale(maps, mesh) == 1, "a mesh rig's variants keep the full blend's scale"
    v = Variants(c, maps)
    white = base_white(c, maps)
    key = variant_key({"mid"})
    coarse, fine = v.compute(key), compute_variant(c, maps, white, key, map_scale=1)
    assert coarse.maps["left"].size == (64, 36) and fine.maps["left"].size == (256, 144)

    def light(variant):
        pairs = {s: (m.alpha, m.beta) for s, m in variant.maps.items() if m is not BLACK_MAPS}
        return luma(predict(c, pairs, 1.0, lost=("mid",)) - predict(c, pairs, 0.0, lost=("mid",)))
    got, want = light(coarse), light(fine)
    fp = c.footprint("mid") & (want > 0.05 * want.max())      # where the others reach
    ratio = got[fp] / want[fp]
    assert np.percentile(np.abs(ratio - 1.0), 99) < 0.01, np.percentile(np.abs(ratio - 1.0), 99)
    assert coarse.kept >= 0.99 * fine.kept


def test_packed_maps_are_the_maps_as_the_wire_carries_them():
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:27, 0:48] / 48.0
    alpha = np.clip(np.stack([0.5 + 0.3 * x, 0.6 - 0.2 * y, 0.4 + 0.1 * x * y], -1) + rng.normal(0, 1e-3, (27, 48, 3)),
                    0, 1).astype(np.float32)
    maps = BlendMaps(alpha, np.zeros((27, 48), np.float32))
    for packed in (maps.packed(), maps.packed(compress=True)):
        assert packed.blend_id == maps.blend_id and packed.size == (48, 27)
        assert packed.encode() == maps.encode()
        a, b = maps.encode()
        np.testing.assert_array_equal(packed.alpha, np.frombuffer(a, "<f2").reshape(27, 48, 3).astype(np.float32))
        assert packed.beta.shape == (27, 48) and not packed.alpha.flags.writeable
        assert BlendMaps.decode(48, 27, *packed.inflated().encode()).blend_id == maps.blend_id
    assert maps.packed().nbytes == 27 * 48 * 8 == maps.nbytes // 2
    assert maps.packed(compress=True).nbytes < maps.packed().nbytes
    assert maps.packed(compress=True).inflated().compressed is False


def test_a_sequence_steadies_where_consecutive_frames_are_one_file():
    from fractions import Fraction

    from coordinator.blending.watchdog import steady_span
    from protos.timeline import Timeline

    shas = ["a", "a", "a", "b", "c", "c", "a"]
    ms = 1_000_000
    tl = Timeline("x", frames=len(shas), rate=Fraction(10), anchor_ns=1000 * ms, loop=True)
    # frame on screen, since, until: a run of "a" for three periods, "b" for one, "c" for two
    assert steady_span(tl, shas, 0) == (0, 1000 * ms, 1300 * ms)          # before the anchor: taken at it
    assert steady_span(tl, shas, 1250 * ms) == (2, 1000 * ms, 1300 * ms)
    assert steady_span(tl, shas, 1300 * ms) == (3, 1300 * ms, 1400 * ms)
    assert steady_span(tl, shas, 1450 * ms) == (4, 1400 * ms, 1600 * ms)
    # the loop joins the last "a" to the first three of the next pass
    assert steady_span(tl, shas, 1650 * ms) == (6, 1600 * ms, 2000 * ms)
    once = Timeline("x", frames=len(shas), rate=Fraction(10), anchor_ns=1000 * ms)
    assert steady_span(once, shas, 1650 * ms) == (6, 1600 * ms, 1700 * ms)
    assert steady_span(once, shas, 1700 * ms) is None                    # the show ended
    assert steady_span(once, ["s"] * 7, 1200 * ms) == (2, 1000 * ms, 1700 * ms)
    assert steady_span(tl.paused_at(1450 * ms), shas, 9000 * ms) == (4, 1450 * ms, None)
