"""Meshes: the bust's shape, OBJ/PLY round trips, errors that name the file."""
from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from sim.errors import MeshError
from sim.mesh import Mesh, bust, load_mesh, save_mesh, table_mesh


@pytest.fixture(scope="module")
def the_bust() -> Mesh:
    return bust()


def test_bust_has_the_papers_size(the_bust):
    lo, hi = the_bust.bounds
    size = hi - lo
    np.testing.assert_allclose(size, [300.0, 250.0, 600.0], atol=2.0)
    assert lo[2] == pytest.approx(0.0, abs=1e-6)  # stands on the table


def test_bust_is_watertight_and_faces_outwards(the_bust):
    # Compare positions, not indices: the uv seam duplicates vertices.
    _, key = np.unique(np.round(the_bust.vertices, 3), axis=0, return_inverse=True)
    f = key.reshape(-1)[the_bust.faces]
    directed = Counter()
    for a, b, c in f:
        for e in ((a, b), (b, c), (c, a)):
            directed[e] += 1
    assert all(n == 1 for n in directed.values()), "an edge is used twice in the same direction"
    assert all(directed[(b, a)] == 1 for (a, b) in directed), "an edge has no opposite: a hole"
    assert the_bust.signed_volume() > 1e7  # mm^3, positive: outward winding
    assert the_bust.uvs is not None and the_bust.uvs.min() >= 0.0 and the_bust.uvs.max() <= 1.0


def test_bust_has_an_overhang_under_the_chin(the_bust):
    n = the_bust.face_normals()
    centers = the_bust.triangles().mean(axis=1)
    chin = (centers[:, 2] > 370) & (centers[:, 2] < 400) & (n[:, 2] < -0.9)
    assert chin.sum() > 10  # downward-facing faces: the head hides them from the ceiling


@pytest.mark.parametrize("name,binary", [("m.obj", True), ("m.ply", True), ("m.ply", False)])
def test_round_trip_keeps_geometry_and_uvs(tmp_path, the_bust, name, binary):
    path = tmp_path / name
    save_mesh(the_bust, path, binary=binary)
    back = load_mesh(path)
    assert back.faces.shape == the_bust.faces.shape
    tri_a = the_bust.triangles()
    tri_b = back.triangles()
    np.testing.assert_allclose(np.sort(tri_a.reshape(-1, 9), axis=0), np.sort(tri_b.reshape(-1, 9), axis=0), atol=1e-3)
    uv_a = the_bust.uvs[the_bust.faces].reshape(-1, 6)
    uv_b = back.uvs[back.faces].reshape(-1, 6)
    np.testing.assert_allclose(np.sort(uv_a, axis=0), np.sort(uv_b, axis=0), atol=1e-5)


def test_obj_polygons_are_triangulated_and_v_is_flipped(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")
    m = load_mesh(path)
    assert m.faces.shape == (2, 3)
    # OBJ's v grows upwards; ours has (0, 0) at the top-left of the content.
    corner = np.flatnonzero(np.all(m.vertices == [0, 0, 0], axis=1))[0]
    np.testing.assert_allclose(m.uvs[corner], [0.0, 1.0])


def test_bad_mesh_files_name_the_problem(tmp_path):
    missing = tmp_path / "nope.obj"
    with pytest.raises(MeshError, match="nope.obj"):
        load_mesh(missing)
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="bad.obj"):
        load_mesh(bad)
    odd = tmp_path / "x.stl"
    odd.write_text("solid")
    with pytest.raises(MeshError, match="unknown mesh format"):
        load_mesh(odd)
    with pytest.raises(ValueError):
        Mesh(np.zeros((3, 2)), np.zeros((1, 3)))


def test_table_mesh_uv_is_the_table_seen_from_above():
    m = table_mesh()
    top_left = np.flatnonzero(np.all(np.isclose(m.uvs, [0, 0]), axis=1))[0]
    np.testing.assert_allclose(m.vertices[top_left], [-600, 300, 0])
    assert m.face_normals()[:, 2].min() > 0.99
