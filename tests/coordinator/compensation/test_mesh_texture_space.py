"""Texture space on a mesh rig, against independent references: the camera's uv map against the room's
ground truth, the numpy form of a node's mesh rendering against the node's own GL renderer, the
dot-grid conflicts against a brute-force search, the recovery of L against a known transport, and
the masked scores against scikit-image."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from bench.compensation_bust import bust_room, mesh_lookup_matrix
from imaging.compensation.mesh_geometry import (
    TexelGrid,
    dot_conflicts,
    masked_quality,
    row_weights,
    texel_extent,
    texel_transport_from_captures,
    texel_windows,
)
from imaging.compensation.texture_space import (
    MeshCaster,
    content_at_view,
    mesh_warp,
    texel_camera_map,
    texels_per_pixel,
)

CONTENT = (64, 48)


@pytest.fixture(scope="module")
def room():
    return bust_room(projector_scale=0.125, camera_scale=0.125, seed=3)


@pytest.fixture(scope="module")
def maps(room):
    b = room.scene.mesh
    cam = room.truth.camera(0)
    pr = room.truth.projector("r2c2")
    with MeshCaster(b.vertices, b.uvs, b.faces) as caster:
        view = caster.view(cam.P, cam.size, CONTENT)
        atlas = caster.atlas(CONTENT)
        proj = caster.view(pr.P, pr.size, CONTENT, near=300.0, far=3000.0)
    return view, atlas, proj


def test_the_cameras_uv_map_is_the_rooms_truth(room, maps):
    view, atlas, _ = maps
    truth = room.truth.surface(0)
    mesh = truth.kind == 2
    assert np.array_equal(view.on_mesh, mesh) and mesh.sum() > 1000
    x = truth.uv[..., 0] * CONTENT[0] - 0.5
    y = truth.uv[..., 1] * CONTENT[1] - 0.5
    assert np.percentile(np.abs(view.x - x)[mesh], 99) < 0.02 and np.percentile(np.abs(view.y - y)[mesh], 99) < 0.02
    # the cosine of the viewing angle (flat triangles here, smooth normals in the room)
    cam = room.truth.camera(0)
    ray = cam.center - truth.points
    cos = np.abs(np.sum(truth.normals * ray, axis=2)) / np.linalg.norm(ray, axis=2)
    assert np.median(np.abs(cos - view.cos)[mesh]) < 0.02
    # texels the camera sees land on camera pixels that see them (a shadow-map test, checked against the uv map)
    tm = texel_camera_map(atlas, cam.P, view)
    assert tm.on_mesh.all() and 0.1 < tm.visible.mean() < 0.5
    idx = np.flatnonzero(tm.visible)
    X, Y = np.rint(tm.position[idx]).astype(int).T
    tx, ty = idx % CONTENT[0], idx // CONTENT[0]
    du = np.abs(view.x[Y, X] - tx)
    du = np.minimum(du, CONTENT[0] - du)       # the seam at the back
    assert np.median(np.maximum(du, np.abs(view.y[Y, X] - ty))) < 0.6
    # narrowing a map made at any angle is the map made with that angle
    narrowed = texel_camera_map(atlas, cam.P, view, min_cos=0.0).at_least(0.25)
    assert np.array_equal(narrowed.visible, tm.visible) and np.array_equal(narrowed.cos, tm.cos)


def test_mesh_warp_is_what_the_nodes_renderer_draws(room, maps):
    """The coordinator's numpy rendering of a mesh pose against node/render (GLSL through EGL)."""
    from node.render.renderer import Mesh as NodeMesh
    from node.render.renderer import Renderer

    _, _, proj = maps
    b = room.scene.mesh
    pr = room.truth.projector("r2c2")
    rng = np.random.default_rng(0)
    content = rng.random((CONTENT[1], CONTENT[0], 3)).astype(np.float32)
    ours = mesh_warp(content, proj)
    w, h = pr.size
    with Renderer.standalone(w, h) as r:
        r.set_projection(pr.P, NodeMesh(b.vertices, b.uvs, b.faces), near=300.0, far=3000.0)
        r.upload("c", content)
        r.render("c")
        node = r.read().copy()
    on = proj.on_mesh
    assert on.sum() > 1000
    diff = np.abs(ours.astype(int) - node[..., :3].astype(int))
    # the same pixels lit; values within one level but on a few pixels along triangle edges
    assert np.mean(diff[on] > 1) < 0.01 and np.mean(diff[~on] > 0) < 0.01
    # and the lookup matrix of the test kit is the same lookup
    B = mesh_lookup_matrix(proj, CONTENT)
    lin = (B @ content.reshape(-1, 3)).reshape(h, w, 3)
    assert np.abs(np.floor(np.clip(lin, 0, 1) * 255 + 0.5) - mesh_warp(content, proj, apply_lut=False)).max() <= 1


def test_content_as_the_camera_sees_it(maps):
    view, _, _ = maps
    content = np.random.default_rng(1).random((CONTENT[1], CONTENT[0], 3)).astype(np.float32)
    seen = content_at_view(content, view)
    ys, xs = np.nonzero(view.on_mesh)
    k = slice(None, None, 97)
    from scipy.ndimage import map_coordinates

    for c in range(3):
        ref = map_coordinates(content[..., c], [view.y[ys[k], xs[k]], view.x[ys[k], xs[k]]], order=1, mode="grid-constant")
        assert np.abs(seen[ys[k], xs[k], c] - ref).max() < 1e-3
    assert not seen[~view.on_mesh].any()


def test_dot_conflicts_match_a_brute_force_search():
    rng = np.random.default_rng(2)
    w, h, radius = 20, 12, 2
    base = rng.integers(0, 60, (w * h, 2))
    seen = rng.random(w * h) < 0.8
    grid = TexelGrid(w, h, 3, 2)
    assert sorted(np.concatenate([grid.dots(k) for k in range(len(grid))])) == list(range(w * h))
    found = dot_conflicts(grid, base, seen, radius)
    expected = np.zeros(w * h, bool)
    for k in range(len(grid)):
        d = [i for i in grid.dots(k) if seen[i]]
        for i in d:
            for j in d:
                if i != j and np.abs(base[i] - base[j]).max() <= 2 * radius:
                    expected[i] = True
    assert np.array_equal(found, expected) and expected.any()


def test_transport_recovered_from_dot_captures_is_the_true_one():
    """Captures synthesised from a known transport inside the windows: recovered exactly (no noise)."""
    rng = np.random.default_rng(4)
    w, h, radius, cam = 12, 9, 1, (40, 50)
    pos = np.stack(np.meshgrid(np.arange(w) * 4.0 + 2.3, np.arange(h) * 4.0 + 3.1), -1).reshape(-1, 2)
    seen = rng.random(w * h) < 0.9
    base, rows, valid = texel_windows(pos, seen, cam, radius)
    truth_vals = rng.random(rows.shape).astype(np.float32) * valid
    from imaging.compensation.transport import assemble_transport

    truth = assemble_transport(truth_vals, rows, valid, cam)
    grid = TexelGrid(w, h, 2, 2)
    black = rng.random((*cam, 3)).astype(np.float32) * 0.01
    caps = [black + (truth @ grid.pattern(k).ravel()).reshape(cam)[:, :, None] for k in range(len(grid))]
    L = texel_transport_from_captures(caps, black, grid=grid, rows=rows, valid=valid)
    assert abs(L - truth).max() < 1e-5
    assert np.array_equal(np.diff(L.tocsc().indptr) > 0, seen)
    with pytest.raises(ValueError, match="needs 4 captures"):
        texel_transport_from_captures(caps[:3], black, grid=grid, rows=rows, valid=valid)


def test_texel_extent_is_the_neighbours_reach():
    pos = np.stack(np.meshgrid(np.arange(5) * 3.0, np.arange(4) * 2.0), -1).reshape(-1, 2)
    pos[7] = np.nan
    e = texel_extent(pos, (4, 5))
    assert np.isnan(e[7]) and np.allclose(e[np.isfinite(e)], 3.0)


def test_masked_scores_are_scikit_images_over_the_mask():
    rng = np.random.default_rng(5)
    t = rng.random((40, 50, 3))
    c = np.clip(t + rng.normal(0, 0.05, t.shape), 0, 1)
    full = masked_quality(t, c, np.ones((40, 50), bool))
    assert full["psnr"] == pytest.approx(peak_signal_noise_ratio(t, c, data_range=1.0), abs=1e-3)
    # scikit-image's mean leaves out a 3-pixel border, the masked mean does not
    assert full["ssim"] == pytest.approx(structural_similarity(t, c, data_range=1.0, channel_axis=2), abs=1e-3)
    mask = np.zeros((40, 50), bool)
    mask[5:30, 10:40] = True
    c2 = c.copy()
    c2[~mask] = 0      # what lies outside the mask does not count
    part = masked_quality(t, c2, mask)
    assert part["psnr"] == pytest.approx(10 * np.log10(1 / np.mean((t[mask] - c[mask]) ** 2)), abs=1e-3)
    assert part["pixels"] == mask.sum()


def test_row_weights_are_the_cosine_of_each_usable_pixel(maps):
    """Brute force: a pixel weighs its cosine over the median of the pixels used, whatever texture area it covers;
    used are the pixels whose every neighbour within the radius sees the mesh at cos >= 0.25, over a measured
    texel, away from the seen texels L lacks, and not across a uv seam."""
    view, _, _ = maps
    radius, cw, ch = 2, CONTENT[0], CONTENT[1]
    measured = np.ones(cw * ch, bool)
    measured[np.random.default_rng(7).choice(cw * ch, 60, replace=False)] = False
    missing_at = np.array([[40.0, 30.0]])
    w = row_weights(view, measured, CONTENT, radius=radius, unmeasured_at=missing_at)
    hc, wc = view.shape
    ok = view.on_mesh & (view.cos >= 0.25)
    area = texels_per_pixel(view)
    used = np.zeros((hc, wc), bool)
    for y in range(hc):
        for x in range(wc):
            y0, y1, x0, x1 = y - radius, y + radius + 1, x - radius, x + radius + 1
            if y0 < 0 or x0 < 0 or y1 > hc or x1 > wc or not ok[y0:y1, x0:x1].all():
                continue
            tx, ty = int(np.rint(view.x[y, x])), int(np.rint(view.y[y, x]))
            if not (0 <= tx < cw and 0 <= ty < ch and measured[ty * cw + tx]):
                continue
            if max(abs(x - 40), abs(y - 30)) <= radius or not (np.isfinite(area[y, x]) and area[y, x] > 0):
                continue
            used[y, x] = True
    assert used.sum() > 500 and np.array_equal(w > 0, used)
    np.testing.assert_allclose(w[used], view.cos[used] / np.median(view.cos[used]), rtol=1e-5)
    # the camera magnifies some texels far more than others; their pixels still weigh their cosine alone
    assert np.percentile(area[used], 90) > 2 * np.percentile(area[used], 10)
