"""The room's glossy material (sim.specular) and its observer (sim.observer).

Off by default and bit for bit as before; the lobe the room renders against a brute-force
evaluation of the Blinn-Phong BRDF written out per pixel; the lobe's energy normalisation by
numerical integration over the hemisphere; the room's truth still equals its captures with gloss.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sim.errors import LayoutError
from sim.observer import parse_point, with_observer
from sim.room import Room
from sim.scene import reference_scene
from sim.specular import Gloss, parse_gloss

GLOSS = Gloss("table", 0.2, 0.05)
OBSERVER = (40.0, -80.0, 900.0)


def white(room: Room) -> None:
    for s in room.all_slots:
        w, h = room.projector_size(s)
        room.set_frame(s, np.full((h, w, 3), 255, np.uint8))


@pytest.fixture(scope="module")
def scene():
    return reference_scene(0.0625, 0.0625, surface="table", jitter=False)


@pytest.fixture(scope="module")
def rooms(scene):
    """The same room without and with a glossy table, seen by the ceiling camera and an observer (camera 1),
    only the bright unit p1 powered, full white."""
    seen = with_observer(scene, OBSERVER, size=(160, 120))
    plain, glossy = Room(seen, noise=False), Room(replace(seen, gloss=(GLOSS,)), noise=False)
    for room in (plain, glossy):
        white(room)
        room.set_active(["p1"])
    return plain, glossy


def test_without_gloss_the_room_renders_exactly_as_before(scene):
    """No gloss, a gloss of strength 0 and an added observer all leave the rig camera's capture bit for bit."""
    rng = np.random.default_rng(3)
    images = []
    for s in (scene, replace(scene, gloss=(Gloss("table", 0.0, 0.05),)), with_observer(scene, OBSERVER, size=(64, 48))):
        room = Room(s, noise=False)
        for slot in room.slots:
            w, h = room.projector_size(slot)
            room.set_frame(slot, rng.integers(0, 256, (h, w, 3), dtype=np.uint8))
        rng = np.random.default_rng(3)
        images.append(room.render_linear(0))
    assert images[0].any()
    assert images[0].tobytes() == images[1].tobytes()
    assert images[0].tobytes() == images[2].tobytes()


def brute_force_lobe(light, eye, point, strength, roughness):
    """k_s (n + 8) / 8 (N.H)^n, N = +z, one point, plain Python."""
    n = 2.0 / roughness**2 - 2.0
    L = [light[k] - point[k] for k in range(3)]
    V = [eye[k] - point[k] for k in range(3)]
    ln, vn = math.sqrt(sum(c * c for c in L)), math.sqrt(sum(c * c for c in V))
    H = [L[k] / ln + V[k] / vn for k in range(3)]
    n_dot_h = H[2] / math.sqrt(sum(c * c for c in H))
    return strength * (n + 8.0) / 8.0 * n_dot_h**n


def test_the_rendered_lobe_is_the_brdf_evaluated_by_brute_force(rooms):
    """Observer pixels around p1's highlight: glossy / diffuse - 1 is pi f_s / albedo at the pixel's table point."""
    plain, glossy = rooms
    obs = 1
    a = plain.render_linear(obs)[:, :, 1].astype(np.float64)
    b = glossy.render_linear(obs)[:, :, 1].astype(np.float64)
    excess = b - a
    assert excess.max() > 5 * a.max()          # a highlight, well above the diffuse light
    cam = glossy.truth.camera(obs)
    lens = glossy.truth.projector("p1").center
    albedo = glossy.scene.table.albedo
    y0, x0 = np.unravel_index(np.argmax(excess), excess.shape)
    picks = [(y0 + dy, x0 + dx) for dy in (-6, -2, 0, 3) for dx in (-5, 0, 1, 4)]
    Kinv = np.linalg.inv(cam.K)
    for y, x in picks:
        ray = cam.R.T @ (Kinv @ np.array([x, y, 1.0]))
        point = cam.center + (-cam.center[2] / ray[2]) * ray
        expected = brute_force_lobe(lens, cam.center, point, GLOSS.strength, GLOSS.roughness) / albedo
        assert b[y, x] / a[y, x] - 1.0 == pytest.approx(expected, rel=2e-5, abs=1e-6), (x, y)
    # the highlight is where this eye sees the lens's mirror image in the table (within a pixel's footprint)
    image = np.array([lens[0], lens[1], -lens[2]])
    mirror = cam.center + cam.center[2] / (cam.center[2] + lens[2]) * (image - cam.center)
    ray = cam.R.T @ (Kinv @ np.array([x0, y0, 1.0]))
    seen = cam.center + (-cam.center[2] / ray[2]) * ray
    assert np.linalg.norm(seen[:2] - mirror[:2]) < 12.0


def test_with_gloss_the_truth_is_still_what_the_capture_applies(rooms):
    plain, glossy = rooms
    lum = np.ones((*glossy.projector_size("p1")[::-1], 3), np.float32)
    for room in (plain, glossy):
        T = room.truth.transport("p1", 1)
        W, H = room.camera_size(1)
        np.testing.assert_allclose((T @ lum[:, :, 1].ravel()).reshape(H, W), room.render_linear(1)[:, :, 1], rtol=1e-4, atol=1e-6)
    # the diffuse part is the matte room's: the lobe is added beside it, from the same irradiance
    a = plain.truth.irradiance("p1", 1)
    b = glossy.truth.irradiance("p1", 1)
    assert np.all(b >= a)
    far = b - a < 1e-9 * b.max()
    assert far.mean() > 0.5 and np.array_equal(a[far], b[far])


@pytest.mark.parametrize("n", [100.0, 1000.0, 5000.0])
def test_the_lobe_reflects_k_s_of_normal_incidence_light(n):
    """Energy normalisation: the integral of f_s cos(theta_o) over the hemisphere, light along the normal, is k_s
    to within 2 / n (Blinn-Phong's (n + 8) / (8 pi) is an approximation that reflects about 1.8 / n too much)."""
    ks = 0.3
    # N.H = cos(theta_o / 2) for a light along the normal; integrate over theta_o in [0, pi/2], phi analytically
    theta = np.linspace(0.0, math.pi / 2, 400_001)
    integrand = ks * (n + 8) / (8 * math.pi) * np.cos(theta / 2) ** n * np.cos(theta) * np.sin(theta) * 2 * math.pi
    total = float(np.sum((integrand[1:] + integrand[:-1]) / 2 * np.diff(theta)))
    assert ks < total < ks * (1.0 + 2.0 / n)


def test_gloss_and_observer_refuse_bad_input_in_one_line(scene):
    assert parse_gloss("table:0.1:0.03") == Gloss("table", 0.1, 0.03)
    for text, words in (("table:0.1", "SURFACE:STRENGTH:ROUGHNESS"), ("floor:0.1:0.1", "not one of table, mesh"),
                        ("table:2:0.1", "strength"), ("table:0.1:0", "roughness"), ("table:x:0.1", "numbers")):
        with pytest.raises(ValueError, match=words) as err:
            parse_gloss(text)
        assert "\n" not in str(err.value)
    with pytest.raises(LayoutError, match="surface this room has"):
        replace(scene, gloss=(Gloss("mesh", 0.1, 0.1),))
    with pytest.raises(ValueError, match="X,Y,Z"):
        parse_point("0,0", what="observer")
    with pytest.raises(LayoutError, match="its own position"):
        with_observer(scene, (0.0, 0.0, 0.0))


def test_a_glossy_bust_shows_the_lobe_of_its_own_normals_and_leaves_the_table_matte():
    """Gloss on the mesh only: the table's pixels render bit for bit as the matte room's; the bust's follow the
    brute-force BRDF at each pixel's point and interpolated normal (the room's truth), for the lens of p1."""
    bust = reference_scene(0.0625, 0.0625, surface="bust", jitter=False)
    bust = replace(bust, projectors=(bust.projector("p1"),))   # one lens: one shadow map to rasterise
    scene = with_observer(bust, (0.0, -800.0, 600.0), target=(0.0, 0.0, 250.0), size=(96, 72), up=(0.0, 0.0, 1.0))
    coat = Gloss("mesh", 0.3, 0.2)
    plain, glossy = Room(scene, noise=False), Room(replace(scene, gloss=(coat,)), noise=False)
    for room in (plain, glossy):
        white(room)
        room.set_active(["p1"])
    obs = len(scene.cameras) - 1
    a = plain.render_linear(obs)[:, :, 1].astype(np.float64)
    b = glossy.render_linear(obs)[:, :, 1].astype(np.float64)
    surface = glossy.truth.surface(obs)
    table, mesh = surface.kind == 1, surface.kind == 2
    assert table.any() and np.array_equal(a[table], b[table])
    lit = mesh & (a > 0.05 * a.max())
    ys, xs = np.nonzero(lit)
    assert len(ys) > 50
    lens, eye = glossy.truth.projector("p1").center, glossy.truth.camera(obs).center
    n = coat.exponent
    checked = 0
    for y, x in zip(ys[::7], xs[::7]):
        p = surface.points[y, x].astype(np.float64)
        N = surface.normals[y, x].astype(np.float64)
        N /= np.linalg.norm(N)
        L, V = (lens - p) / np.linalg.norm(lens - p), (eye - p) / np.linalg.norm(eye - p)
        H = (L + V) / np.linalg.norm(L + V)
        expected = coat.strength * (n + 8) / 8 * max(float(N @ H), 0.0) ** n if N @ L > 0 and N @ V > 0 else 0.0
        assert (b[y, x] / a[y, x] - 1.0) * scene.mesh_albedo == pytest.approx(expected, rel=1e-3, abs=1e-4), (x, y)
        checked += expected > 0.05
    assert checked > 3                           # some of the checked pixels are in the highlight


def test_shadowless_room_takes_a_gloss_and_an_observer():
    import argparse

    from sim.cli import build_room, configure

    parser = argparse.ArgumentParser(prog="shadowless room")
    configure(parser)
    room = build_room(parser.parse_args(["--gloss", "table:0.1:0.02", "--observer", "0,-60,900", "--projector-scale", "0.1"]))
    assert room.scene.gloss == (Gloss("table", 0.1, 0.02),)
    assert [c.name for c in room.scene.cameras] == ["ceiling", "observer"]
    assert np.allclose(room.scene.cameras[1].pinhole.center, (0.0, -60.0, 900.0))
    with pytest.raises(SystemExit):
        parser.parse_args(["--gloss", "table:0.1"])
