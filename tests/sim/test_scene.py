"""Scenes: the reference rig, the paper's subsets, layout files."""
from __future__ import annotations

import numpy as np
import pytest

from sim.errors import LayoutError, UnknownSlotError
from sim.optics import irradiance_factor
from sim.scene import SUBSETS, load_layout, reference_scene, write_layout


@pytest.fixture(scope="module")
def scene():
    return reference_scene()


def test_subsets_have_the_papers_sizes_and_shapes():
    sizes = {name: len(slots) for name, slots in SUBSETS.items()}
    assert sizes == {"P1": 1, "P9D": 9, "P9W": 9, "P13": 13, "P17": 17, "P20": 20, "P25": 25}
    assert set(SUBSETS["P9D"]) == {f"r{r}c{c}" for r in (1, 2, 3) for c in (1, 2, 3)}
    assert set(SUBSETS["P9W"]) == {f"r{r}c{c}" for r in (0, 2, 4) for c in (0, 2, 4)}
    assert "r2c2" not in SUBSETS["P20"] and "r2c2" in SUBSETS["P17"] and "r2c2" in SUBSETS["P13"]
    for name, slots in SUBSETS.items():
        assert len(set(slots)) == len(slots), name


def test_reference_rig_layout(scene):
    assert scene.slots == [f"r{r}c{c}" for r in range(5) for c in range(5)]
    assert "p1" in scene.all_slots and not scene.projector("p1").powered
    for name, slots in SUBSETS.items():
        for s in slots:
            scene.projector(s)
    # rows grow along +y, columns along +x, all on the ceiling plane
    c00, c04, c40 = (scene.projector(s).native.center for s in ("r0c0", "r0c4", "r4c0"))
    assert c04[0] - c00[0] == pytest.approx(1000, abs=10) and c40[1] - c00[1] == pytest.approx(1000, abs=10)
    assert c00[2] == pytest.approx(1400, abs=5)
    assert scene.projector("r0c0").size == (320, 200) and scene.projector("r0c0").native.size == (1280, 800)
    assert scene.cameras[0].size == (648, 486)
    with pytest.raises(UnknownSlotError, match="r0c0"):
        scene.projector("r9c9")


def test_every_footprint_covers_the_table(scene):
    corners = np.array([[x, y, 0.0] for x in (-600, 600) for y in (-300, 300)])
    for p in scene.projectors:
        pix, z = p.pinhole.project(corners)
        w, h = p.size
        assert np.all(z > 0)
        assert np.all((pix[:, 0] > 0) & (pix[:, 0] < w - 1) & (pix[:, 1] > 0) & (pix[:, 1] < h - 1)), p.slot
    pix, _ = scene.cameras[0].pinhole.project(corners)
    W, H = scene.cameras[0].size
    assert np.all((pix[:, 0] > 0) & (pix[:, 0] < W - 1) & (pix[:, 1] > 0) & (pix[:, 1] < H - 1))


def test_units_differ_and_the_seed_reproduces_them():
    a, b, c = reference_scene(seed=1), reference_scene(seed=1), reference_scene(seed=2)
    ga = np.array([p.response.gamma for p in a.projectors])
    np.testing.assert_array_equal(ga, [p.response.gamma for p in b.projectors])
    assert not np.allclose(ga, [p.response.gamma for p in c.projectors])
    assert ga.std() > 0.02
    assert not np.allclose(a.projector("r0c0").native.center, c.projector("r0c0").native.center)


def test_the_bright_unit_equals_the_25_at_the_table_centre(scene):
    point, up = np.zeros(3), np.array([0.0, 0.0, 1.0])

    def e(p):
        return p.peak * float(irradiance_factor(p.native.center, p.native.axis, point, up, falloff=p.falloff))

    total = sum(e(scene.projector(s)) for s in SUBSETS["P25"])
    assert e(scene.projector("p1")) == pytest.approx(total, rel=1e-9)


def test_layout_round_trip(tmp_path, scene):
    path = tmp_path / "rig.toml"
    write_layout(scene, path)
    back = load_layout(path)
    assert back.all_slots == scene.all_slots and back.slots == scene.slots
    for p, q in zip(scene.projectors, back.projectors):
        np.testing.assert_allclose(q.pinhole.P, p.pinhole.P, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(q.response.gamma, p.response.gamma)
        assert q.peak == pytest.approx(p.peak) and q.focus == pytest.approx(p.focus)
    np.testing.assert_allclose(back.cameras[0].pinhole.P, scene.cameras[0].pinhole.P, rtol=1e-6, atol=1e-6)
    assert back.cameras[0].gain == pytest.approx(scene.cameras[0].gain, rel=1e-6)


def test_any_layout_from_a_file(tmp_path):
    path = tmp_path / "three.toml"
    path.write_text(
        """
name = "three on a wall"
[table]
size = [800, 500]
[mesh]
builtin = "bust"
position = [100, 0, 0]
[[projector]]
slot = "left"
position = [-900, 0, 900]
target = [0, 0, 200]
throw_ratio = 1.1
[[projector]]
slot = "right"
position = [900, 100, 900]
target = [0, 0, 200]
gamma = [2.0, 2.1, 2.2]
black = 0.004
[[projector]]
position = [0, 0, 1500]
powered = false
[[camera]]
position = [0, -1200, 1000]
target = [0, 0, 200]
up = [0, 0, 1]
resolution = [1280, 960]
focal_px = 1100
"""
    )
    s = load_layout(path, projector_scale=0.5, camera_scale=0.5)
    assert s.all_slots == ["left", "right", "p2"] and s.slots == ["left", "right"]
    assert s.table.size == (800.0, 500.0)
    assert s.mesh is not None and s.mesh.bounds[0][0] == pytest.approx(-50.0, abs=1)
    assert s.projector("left").native.K[0, 0] == pytest.approx(1.1 * 1280)
    np.testing.assert_allclose(s.projector("right").response.gamma, [2.0, 2.1, 2.2])
    assert s.cameras[0].size == (640, 480)
    pix, _ = s.cameras[0].pinhole.project(np.array([0.0, 0.0, 200.0]))
    assert pix == pytest.approx([319.5, 239.5], abs=1e-6)


@pytest.mark.parametrize(
    "text,match",
    [
        ("[[camera]]\nposition = [0, 0, 1000]\n", "needs at least one \\[\\[projector\\]\\]"),
        ("[[projector]]\nslot = 'a'\n[[camera]]\nposition = [0, 0, 1]\n", "projector.*#1 \\(a\\).*position"),
        ("[[projector]]\nposition = [0, 0]\n[[camera]]\nposition = [0, 0, 1]\n", "3 finite numbers"),
        ("[[projector]\n", "not valid TOML"),
        ("colour = 'red'\n", "unknown top-level keys"),
    ],
)
def test_bad_layouts_name_the_entry(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(LayoutError, match=match):
        load_layout(path)


def test_three_cameras_keep_the_ceiling_one_and_see_the_bust_and_the_table(scene):
    three = reference_scene(surface="bust", cameras=3)
    assert [c.name for c in three.cameras] == ["ceiling", "front-left", "back-right"]
    np.testing.assert_array_equal(three.cameras[0].pinhole.P, scene.cameras[0].pinhole.P)
    bust_box = np.array([[x, y, z] for x in (-150, 150) for y in (-125, 125) for z in (0, 600)], np.float64)
    table_middle = np.array([[x, y, 0.0] for x in (-400, 400) for y in (-250, 250)])
    for cam in three.cameras[1:]:
        pix, z = cam.pinhole.project(np.vstack([bust_box, table_middle]))
        W, H = cam.size
        assert np.all(z > 0) and np.all((pix >= 0) & (pix < [W, H])), cam.name
        assert cam.gain > 0
    with pytest.raises(ValueError, match="1 or 3 cameras"):
        reference_scene(cameras=2)
