"""The bench kit's true light transport of a mesh rig (:func:`bench.compensation_bust.truth_mesh_transport`)
against the room itself: ``L x`` is what each camera records of the texture ``x`` sent to the nodes as the jobs
send it (chart edges padded), for the ceiling camera and an oblique one; and the per-camera comparison of a
stacked ``L`` (:func:`bench.compensation_bust.mesh_transport_errors`) against a brute-force one."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy import ndimage

from bench.compensation_bust import (
    bust_room,
    make_bust_rig,
    mesh_transport_errors,
    truth_mesh_transport,
)
from imaging.compensation.texture_space import MeshCaster, padded, padding_index
from shadowless.room_driver import RoomDriver

CONTENT = (128, 96)
SLOTS = ["r2c2", "r1c3"]


@pytest.fixture(scope="module")
def rig_in_room(tmp_path_factory):
    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2, noise=False, cameras=3)
    rig = make_bust_rig(tmp_path_factory.mktemp("bust-truth") / "rig", room, SLOTS, content_size=CONTENT, luts=True,
                        cameras=3)
    mesh = rig.slot(SLOTS[0]).pose.mesh
    with MeshCaster(mesh.vertices, mesh.uvs, mesh.faces) as caster:
        on = np.isfinite(caster.atlas(CONTENT)).all(axis=2)
    return room, rig, RoomDriver(room, rig, cameras=3), on


@pytest.mark.parametrize("camera", [0, 1])
def test_truth_times_a_texture_is_what_the_camera_records_of_it_padded(rig_in_room, camera):
    """Texels on the mesh along its chart edges, lit: the nodes are sent the texture with its padding (as every
    job sends it), so the room lights the padding texels too; the truth must hold their light."""
    room, rig, driver, on = rig_in_room
    edge = on & ndimage.binary_dilation(~on)
    x = np.zeros((CONTENT[1], CONTENT[0]), np.float32)
    x[edge] = 1.0
    shown = padded(x, padding_index(on))
    assert (shown > 0).sum() > 1.5 * edge.sum()             # the padding lights as many texels again
    driver.render_content(None)
    black = room.render_linear(camera).mean(axis=2)
    driver.render_content(np.repeat(shown[:, :, None], 3, axis=2))
    seen = (room.render_linear(camera).mean(axis=2) - black).ravel()
    L = truth_mesh_transport(room, rig, SLOTS, camera=camera)
    predicted = L @ x.ravel()
    assert seen.max() > 0.01
    # the nodes' 8-bit LUT outputs are all that differ
    assert np.linalg.norm(predicted - seen) / np.linalg.norm(seen) < 0.03


def test_each_camera_is_compared_over_the_texels_it_measured():
    rng = np.random.default_rng(3)
    n, rows = 40, 30

    def rand(density):
        return sp.random(rows, n, density=density, random_state=rng, format="csr", dtype=np.float64)

    truths = [rand(0.3), rand(0.3)]
    L = sp.vstack([truths[0] * 1.1, truths[1] * 0.8], format="lil")
    L[:rows, 30:] = 0                                           # camera 0 did not measure texels 30..39
    L[rows:, :10] = 0                                           # camera 1 did not measure texels 0..9
    L = sp.csr_matrix(L)
    L.eliminate_zeros()
    out = mesh_transport_errors(L, truths)
    assert out["per_camera"] == pytest.approx([0.1, 0.2])
    # brute force: each camera's truth only in the columns it measured, over the columns some camera measured
    dense, t = L.toarray(), np.vstack([m.toarray() for m in truths])
    t[:rows][:, (dense[:rows] == 0).all(axis=0)] = 0
    t[rows:][:, (dense[rows:] == 0).all(axis=0)] = 0
    cols = (dense != 0).any(axis=0)
    assert out["stacked"] == pytest.approx(np.linalg.norm(dense[:, cols] - t[:, cols]) / np.linalg.norm(t[:, cols]))
