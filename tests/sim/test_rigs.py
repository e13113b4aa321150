"""Rigs whose projectors only partly overlap: the 3x1 wall and the projectors on the walls around
the bust, as builders, as shipped layout files, as rooms and as rigs (`rig init --layout`)."""
from __future__ import annotations

import tomllib

import numpy as np
import pytest

from coordinator.rig import parse_config
from protos.layout import read_layout
from sim.rigs import LAYOUTS, bust_walls_layout, bust_walls_scene, layout_path, wall_layout, wall_scene
from sim.room import Room
from sim.scene import load_layout

SCALE = dict(projector_scale=0.125, camera_scale=0.125)


def footprint_x(room: Room, slot: str) -> tuple[float, float]:
    """The x extent (mm) of the surface ``slot`` lights, from the truth."""
    lit = np.isfinite(room.truth.projector_coordinates(slot)[..., 0])
    xs = room.truth.surface().points[..., 0][lit]
    return float(xs.min()), float(xs.max())


def test_the_shipped_files_are_the_builders_documents():
    assert tomllib.loads(layout_path("wall-3x1").read_text()) == wall_layout(3, 0.2)
    assert tomllib.loads(layout_path("bust-walls").read_text()) == bust_walls_layout(6)
    assert set(LAYOUTS) == {"wall-3x1", "bust-walls"}
    with pytest.raises(ValueError, match="no shipped layout 'nope'"):
        layout_path("nope")
    with pytest.raises(ValueError, match="overlap must be"):
        wall_layout(3, 0.7)


@pytest.mark.parametrize("columns,overlap", [(3, 0.2), (4, 0.35)])
def test_wall_footprints_overlap_as_asked(columns, overlap):
    room = Room(wall_scene(columns, overlap, **SCALE), noise=False)
    assert room.slots == [f"r0c{c}" for c in range(columns)]
    spans = [footprint_x(room, s) for s in room.slots]
    inner = spans[1]
    width = inner[1] - inner[0]
    assert width == pytest.approx(500, rel=0.02)                         # a whole footprint on the surface
    for (a0, a1), (b0, b1) in zip(spans, spans[1:]):
        assert a0 < b0 < a1 < b1
        assert (a1 - b0) / width == pytest.approx(overlap, abs=0.01)
    count = room.truth.illumination_count()
    seen = room.truth.surface().kind > 0
    assert count[seen].min() == 1 and count[seen].max() == 2            # every point lit, by one or two
    assert np.mean(count[seen] == 2) == pytest.approx((columns - 1) * overlap / (columns - (columns - 1) * overlap), abs=0.03)
    # and a flat white shows the seams: the overlaps are about twice as bright as the rest
    for s in room.slots:
        room.set_frame(s, np.full((*room.projector_size(s)[::-1], 3), 255, np.uint8))
    img = room.render_linear()[..., 1]
    ratio = np.median(img[seen & (count == 2)]) / np.median(img[seen & (count == 1)])
    assert 1.7 < ratio < 2.2 and img.max() < 1.0


def test_projectors_on_the_walls_each_light_one_side_of_the_bust():
    scene = bust_walls_scene(**SCALE)
    room = Room(scene, noise=False)
    assert room.slots == [f"w{k}" for k in range(6)] and len(scene.cameras) == 3
    kind = room.truth.surface().kind
    bust = kind == 2
    lit = {s: np.isfinite(room.truth.projector_coordinates(s)[..., 0]) & bust for s in room.slots}
    count = sum(m.astype(int) for m in lit.values())
    share = {s: m.sum() / bust.sum() for s, m in lit.items()}
    assert max(share.values()) < 0.8                                     # no projector reaches all the bust ...
    assert np.mean(count[bust] >= 2) > 0.5 and np.mean(count[bust] >= 1) > 0.95   # ... yet together they do, mostly twice
    # the front projector reaches the face, the back one does not
    front = room.truth.projector("w0").center
    assert front[1] > 1000 and room.truth.projector("w3").center[1] < -1000


def test_rig_init_of_the_wall_makes_a_three_slot_rig(tmp_path, shadowless_main):
    code, out, err = shadowless_main("rig", "init", str(tmp_path / "wall"), "--layout", str(layout_path("wall-3x1")))
    assert code == 0, err
    cfg = parse_config((tmp_path / "wall" / "rig.toml").read_text())
    assert list(cfg.slots) == ["r0c0", "r0c1", "r0c2"]
    assert set(cfg.slots.values()) == {(1280, 800)}
    assert (cfg.content_width, cfg.content_height) == (1260, 272)      # 1 px per mm of the wall
    # a layout with a [photometry] section is a rig all the same: the coordinator ignores the room's light
    text = layout_path("wall-3x1").read_text() + "\n[photometry]\nbrightness_spread = 0.15\nhotspot = 0.2\n"
    (tmp_path / "lit.toml").write_text(text)
    assert read_layout(tmp_path / "lit.toml").photometry == {"brightness_spread": 0.15, "hotspot": 0.2}
    code, out, err = shadowless_main("rig", "init", str(tmp_path / "lit"), "--layout", str(tmp_path / "lit.toml"))
    assert code == 0, err
    assert list(parse_config((tmp_path / "lit" / "rig.toml").read_text()).slots) == ["r0c0", "r0c1", "r0c2"]
    assert load_layout(tmp_path / "lit.toml").projector("r0c1").profile.hotspot == 0.2


@pytest.mark.parametrize("name", ["table", "wall"])
def test_one_call_builds_the_same_room_in_process_and_as_a_process(name):
    import argparse

    from sim import cli
    from sim.rigs import BENCH_LIGHT, room_argv, scene

    parser = argparse.ArgumentParser()
    cli.configure(parser)
    argv = room_argv(name, photometry=BENCH_LIGHT, seed=3, **SCALE)
    served = cli.build_room(parser.parse_args(argv)).scene
    built = scene(name, photometry=BENCH_LIGHT, seed=3, **SCALE)
    assert [p.slot for p in served.projectors] == [p.slot for p in built.projectors]
    for a, b in zip(served.projectors, built.projectors):
        np.testing.assert_array_equal(a.pinhole.P, b.pinhole.P)
        assert a.peak == b.peak and a.white.tolist() == b.white.tolist() and a.profile == b.profile
    assert [c.gain for c in served.cameras] == [c.gain for c in built.cameras]
    with pytest.raises(ValueError, match="no room 'hall'"):
        scene("hall")
