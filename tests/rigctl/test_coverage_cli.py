"""`shadowless coverage`: a mesh rig read offline, its coverage stored, pictured and summarised."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from coordinator.calibration.options import rig_defaults
from coordinator.coverage_figure import NOT_REACHED_BGR, count_colours, orbit_camera
from coordinator.coverage_store import load_coverage
from coordinator.rig import HomographyPose, ProjectionPose, Rig, init_rig, mesh_with_id
from protos.mesh_files import read_mesh

SLOTS = ["r0c0", "r0c4", "r2c2", "r4c0", "r4c4"]


@pytest.fixture(scope="module")
def bust_rig(tmp_path_factory):
    """A rig whose slots carry the room's true 3x4 poses onto the bust (what 3D calibration stores)."""
    from sim.scene import reference_scene

    scene = reference_scene(projector_scale=0.125, camera_scale=0.125, surface="bust")
    d = tmp_path_factory.mktemp("rig") / "bust"
    init_rig(d, name="bust", slots=SLOTS + ["spare"], width=160, height=100)
    rig = Rig(d)
    m = scene.mesh
    mesh = mesh_with_id(m.vertices, m.uvs, m.faces)
    for s in SLOTS:
        p = scene.projector(s).pinhole
        rig.update_slot(s, pose=ProjectionPose(p.P, mesh), size=p.size)
    return d, m


@pytest.fixture
def run(shadowless_main):
    """``run(*argv)``: `shadowless coverage ARGV...` as (exit status, stdout, stderr)."""
    return lambda *argv: shadowless_main("coverage", *argv)


def test_coverage_is_stored_pictured_and_summarised(bust_rig, run, tmp_path):
    d, mesh = bust_rig
    png = tmp_path / "fig.png"
    code, out, err = run("--rig-dir", str(d), "--json", "--texture", "128x128", "--view", "0,20",
                         "--view", "180,20", "--panel", "160x160", "--out", str(png))
    assert code == 0, err
    doc = json.loads(out)
    assert doc["slots"] == 5 and sorted(doc["per_slot"]) == SLOTS             # "spare" has no pose
    assert "coverage: 5 projectors" in err
    cov = load_coverage(d / "coverage" / "coverage.npz")
    assert json.loads((d / "coverage" / "coverage.json").read_text())["per_slot"] == doc["per_slot"]
    # the summary is the stored map's: per slot the area of the texels it reaches
    for k, slot in enumerate(cov.slots):
        reached = float(cov.area[cov.reach[k] & cov.mask].sum())
        assert doc["per_slot"][slot]["reach_mm2"] == pytest.approx(reached, abs=0.1)
    assert doc["count_min"] >= 1 and doc["count_median"] <= 5
    assert doc["surface_mm2"] == pytest.approx(float(cov.area.sum()), rel=1e-4)
    img = cv2.imread(str(png))
    layout = doc["layout"]
    assert img.shape[:2] == (layout["size"][1], layout["size"][0])
    assert list(layout["panels"]) == ["az 0 el 20", "az 180 el 20"]
    x0, y0, x1, y1 = layout["colorbar"]
    colours = count_colours(5)
    assert tuple(img[y0 + 1, x0 + 2]) == tuple(colours[5]) and tuple(img[y1 - 2, x0 + 2]) == NOT_REACHED_BGR
    # each panel shows the bust: about as many coloured pixels as the mesh covers in that view
    px0, py0, px1, py1 = layout["panels"]["az 0 el 20"]
    panel = img[py0:py1, px0:px1]
    seen = np.any(panel != 255, axis=-1)
    dev = orbit_camera(mesh.vertices, 0, 20, size=(160, 160))
    uv, _ = dev.project(mesh.vertices.astype(np.float64))
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    assert lo.min() > 0 and hi.max() < 160                               # the framing keeps it whole
    ys, xs = np.nonzero(seen)
    assert xs.min() == pytest.approx(lo[0], abs=3) and xs.max() == pytest.approx(hi[0], abs=3)
    assert ys.min() == pytest.approx(lo[1], abs=3) and ys.max() == pytest.approx(hi[1], abs=3)


def test_the_table_lists_every_slot(bust_rig, run):
    d, _ = bust_rig
    code, out, _ = run("--rig-dir", str(d), "--texture", "64x64", "--slots", "r0c0,r2c2", "--panel", "96x96")
    assert code == 0
    lines = out.splitlines()
    assert lines[0].startswith("rig bust  mesh ") and "2 projectors" in lines[0]
    assert [line.split()[0] for line in lines if line.startswith("r")][-2:] == ["r0c0", "r2c2"]
    assert (d / "coverage" / "coverage.png").is_file()


@pytest.mark.parametrize("argv, message", [
    (["--view", "10"], "is not a view"),
    (["--view", "0,120"], "elevation must be -90..90"),
    (["--view", "camera"], "no calibrated camera in this rig"),
    (["--slots", "spare"], "have no 3D pose"),
    (["--slots", "nope"], "slot 'nope' is not in rig"),
])
def test_mistakes_are_one_line(bust_rig, run, argv, message):
    d, _ = bust_rig
    code, _, err = run("--rig-dir", str(d), "--texture", "32x32", *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_a_planar_rig_is_refused(tmp_path, run):
    d = tmp_path / "table"
    init_rig(d, name="table", slots=["a"], width=64, height=64)
    Rig(d).update_slot("a", pose=HomographyPose(np.eye(3)))
    code, _, err = run("--rig-dir", str(d))
    assert code == 2 and "its poses are planar" in err
    code, _, err = run("--rig-dir", str(tmp_path / "none"))
    assert code == 2 and "not a rig directory" in err


def test_a_planned_bust_rig_has_the_coverage_of_the_room_poses(bust_rig, tmp_path, run, shadowless_main):
    """`rig init --layout` of the room's own layout, then --planned: the same figures as the rig that
    holds the room's true poses (what 3D calibration stores), texel for texel."""
    from dataclasses import replace

    from sim.scene import reference_scene, write_layout

    d, _ = bust_rig
    scene = reference_scene(projector_scale=0.125, camera_scale=0.125, surface="bust")
    layout = tmp_path / "bust.toml"
    write_layout(replace(scene, projectors=tuple(p for p in scene.projectors if p.slot in SLOTS)), layout)
    planned = tmp_path / "planned"
    assert shadowless_main("rig", "init", str(planned), "--layout", str(layout), "--resolution", "160x100")[0] == 0
    # the object stays in the rig, as planned, for calibration to pose the projectors onto
    rig = Rig(planned)
    assert rig_defaults(planned)[0] == {"mesh": "object.obj"}
    obj = read_mesh(planned / "object.obj")
    placed = next(st.planned.mesh for st in rig.slots.values())
    assert mesh_with_id(obj.vertices, obj.uvs, obj.faces).mesh_id == placed.mesh_id
    code, out, err = run("--rig-dir", str(d), "--json", "--texture", "96x96", "--panel", "96x96")
    assert code == 0, err
    truth = json.loads(out)
    code, out, err = run("--rig-dir", str(planned), "--json", "--texture", "96x96", "--panel", "96x96")
    assert code == 2 and "pass --planned" in err                           # never the plan unasked
    code, out, err = run("--rig-dir", str(planned), "--planned", "--json", "--texture", "96x96", "--panel", "96x96")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["poses"] == "planned" and truth["poses"] == "calibrated" and "as planned" in err
    assert doc["mesh"] == truth["mesh"]                                    # the room's bust, the same arrays
    a, b = load_coverage(d / "coverage" / "coverage.npz"), load_coverage(planned / "coverage" / "coverage.npz")
    assert a.slots == b.slots and (a.mask == b.mask).all()
    assert (a.count[a.mask] == b.count[b.mask]).mean() >= 0.999
    for slot in SLOTS:
        assert doc["per_slot"][slot]["reach_mm2"] == pytest.approx(truth["per_slot"][slot]["reach_mm2"], rel=1e-3)


def test_a_planned_table_counts_the_projectors_whose_image_holds_each_point(tmp_path, run, shadowless_main):
    """On the table nothing hides anything: a point counts the projectors it projects inside of (brute force)."""
    from sim.scene import load_layout

    layout = tmp_path / "t.toml"
    layout.write_text('name = "t"\n[table]\nsize = [1200, 600]\n'
                      + "".join(f'[[projector]]\nslot = "{s}"\nposition = [{x}, {y}, 1400]\ntarget = [{x / 2}, 0, 0]\n'
                                f"resolution = [1280, 800]\nfocal_px = 2400\n"
                                for s, x, y in (("a", -400, 0), ("b", 0, 300), ("c", 400, -100)))
                      + "[[camera]]\nposition = [0, -125, 1400]\n")
    d = tmp_path / "rig"
    assert shadowless_main("rig", "init", str(d), "--layout", str(layout))[0] == 0
    code, out, err = run("--rig-dir", str(d), "--planned", "--json", "--texture", "150x75", "--panel", "120x120")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["views"] == ["az 0 el 90"] and doc["texture"] == [150, 75]
    cov = load_coverage(d / "coverage" / "coverage.npz")
    assert cov.mask.all()
    np.testing.assert_allclose(cov.area.sum(), 1200 * 600, rtol=1e-4)
    pts = cov.points.reshape(-1, 3).astype(np.float64)
    count = np.zeros(len(pts), int)
    for p in load_layout(layout, projector_scale=1.0).projectors:
        uv, depth = p.native.project(pts)
        w, h = p.native.size
        count += ((depth > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))
    assert set(np.unique(count)) == {0, 1, 2, 3}                           # the long focal length leaves gaps
    assert (cov.count.ravel() == count).mean() >= 0.999
    assert doc["lit_pct"] == pytest.approx(100 * (count > 0).mean(), abs=0.2)
