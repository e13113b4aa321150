"""protos/mesh_files.py: OBJ and PLY read and written once for the room, calibration and MPCDI."""
from __future__ import annotations

import numpy as np
import pytest

from protos.mesh_files import MeshFileError, format_obj, format_ply, parse_mesh, read_mesh


def _mesh(seed=0, n=40):
    rng = np.random.default_rng(seed)
    v = rng.normal(0, 300, (n, 3))
    f = np.array([[i, (i + 1) % n, (i + 7) % n] for i in range(n)], np.int64)
    uv = rng.random((n, 2))
    return v, f, uv


def test_exact_obj_reads_back_bit_for_bit():
    v, f, uv = _mesh()
    m = parse_mesh(format_obj(v, f, uv, exact=True).encode(), ".obj")
    np.testing.assert_array_equal(m.vertices, v)
    np.testing.assert_array_equal(m.faces, f)
    np.testing.assert_array_equal(m.uvs, 1.0 - (1.0 - uv))   # v is flipped twice


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip_at_float32(binary):
    v, f, uv = _mesh(1)
    m = parse_mesh(format_ply(v, f, uv, binary=binary), ".ply")
    np.testing.assert_allclose(m.vertices, v.astype(np.float32), rtol=1e-6)
    np.testing.assert_array_equal(m.faces, f)
    np.testing.assert_allclose(m.uvs, uv, atol=1e-6)


def test_obj_polygons_fan_negative_indices_and_v_up():
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf -4/-4 -3/-3 -2/-2 -1/-1 # quad\n"
    m = parse_mesh(text.encode(), ".obj")
    assert m.faces.shape == (2, 3) and len(m.vertices) == 4
    corner = np.flatnonzero(np.all(m.vertices == [0, 0, 0], axis=1))[0]
    np.testing.assert_array_equal(m.uvs[corner], [0.0, 1.0])


def test_a_vertex_with_two_uvs_is_split():
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\nf 1/1 2/2 3/3\nf 1/4 3/3 2/2\n"
    m = parse_mesh(text.encode(), ".obj")
    assert len(m.vertices) == 4 and m.uvs.shape == (4, 2)


@pytest.mark.parametrize("data,suffix,words", [
    (b"v 0 0 0\nf 1 2 3\n", ".obj", "missing vertex"),
    (b"v 0 0 0\nv 1 0 0\nf 1 2\n", ".obj", "fewer than 3"),
    (b"vt 0 0\n", ".obj", "no vertices"),
    (b"v 0 0 0\n", ".obj", "no faces"),
    (b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", ".obj", "NaN"),
    (b"v x y z\n", ".obj", "malformed OBJ"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n", ".ply", "x, y, z"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
     b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n",
     ".ply", "missing vertex"),
    (b"solid x\n", ".stl", "unknown mesh format"),
    (b"plyx", ".ply", "not a PLY"),
])
def test_bad_files_say_what_is_wrong(data, suffix, words):
    with pytest.raises(MeshFileError, match=words):
        parse_mesh(data, suffix)


def test_read_mesh_names_the_file(tmp_path):
    with pytest.raises(MeshFileError, match="cannot read mesh .*none.obj"):
        read_mesh(tmp_path / "none.obj")
    (tmp_path / "bad.obj").write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(MeshFileError, match="bad.obj.*missing vertex"):
        read_mesh(tmp_path / "bad.obj")
