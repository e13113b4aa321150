"""The bust's even-density uv atlas: the same surface as the cylindrical bust, charts that do not overlap,
texels of about one size on the surface, and the padding between charts."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.csgraph import connected_components

from sim.mesh import bust

TEXTURE = (96, 72)


def _texel_stretch(mesh, texture) -> np.ndarray:
    """Per face, the longest a texel is on the surface (mm): the largest singular value of the map from texel
    coordinates to world mm (the face's edges in 3D against its edges in texels)."""
    tri = mesh.triangles()
    uv = mesh.uvs[mesh.faces].astype(np.float64) * np.array(texture)
    E3 = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]], axis=2)        # (F, 3, 2)
    Euv = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)           # (F, 2, 2)
    ok = np.abs(np.linalg.det(Euv)) > 1e-9
    J = E3[ok] @ np.linalg.inv(Euv[ok])
    return np.linalg.svd(J, compute_uv=False)[:, 0]


def _coverage(mesh, texture, scale: int = 2, faces=None) -> np.ndarray:
    """How many triangles cover each sample point (centres of a grid ``scale`` times finer than the texels)."""
    h, w = texture[1] * scale, texture[0] * scale
    cnt = np.zeros((h, w), np.int32)
    f = mesh.faces if faces is None else mesh.faces[faces]
    for t in mesh.uvs[f].astype(np.float64) * np.array(texture) * scale:
        (x0, y0), (x1, y1) = np.floor(t.min(0)).astype(int), np.ceil(t.max(0)).astype(int)
        ys, xs = np.mgrid[max(y0, 0):min(y1 + 1, h), max(x0, 0):min(x1 + 1, w)]
        px, py = xs + 0.5, ys + 0.5
        e = [(q[0] - p[0]) * (py - p[1]) - (q[1] - p[1]) * (px - p[0]) for p, q in ((t[1], t[2]), (t[2], t[0]),
                                                                                   (t[0], t[1]))]
        inside = ((e[0] > 0) & (e[1] > 0) & (e[2] > 0)) | ((e[0] < 0) & (e[1] < 0) & (e[2] < 0))
        cnt[ys[inside], xs[inside]] += 1
    return cnt


@pytest.fixture(scope="module")
def pair():
    return bust(segments=48, rings=70), bust(segments=48, rings=70, atlas=TEXTURE)


def test_the_atlas_is_the_same_surface(pair):
    cyl, atl = pair
    a = np.sort(np.sort(cyl.triangles().reshape(-1, 9), axis=1), axis=0)
    b = np.sort(np.sort(atl.triangles().reshape(-1, 9), axis=1), axis=0)
    np.testing.assert_allclose(a, b, atol=1e-3)
    assert atl.signed_volume() == pytest.approx(cyl.signed_volume(), rel=1e-6)
    assert atl.uvs.min() >= 0.0 and atl.uvs.max() <= 1.0


def test_texels_have_about_one_size_on_the_surface(pair):
    cyl, atl = pair
    spread = {}
    for name, m in (("cylindrical", cyl), ("atlas", atl)):
        stretch = _texel_stretch(m, TEXTURE)
        spread[name] = float(np.percentile(stretch, 98) / np.median(stretch))
    # the cylindrical map stretches texels over the crown and shoulders (v is height); the atlas does not
    assert spread["atlas"] < 2.0 and spread["cylindrical"] > 2 * spread["atlas"], spread


def test_charts_do_not_overlap_and_keep_their_padding(pair):
    _, atl = pair
    cnt = _coverage(atl, TEXTURE)
    poles = np.bincount(atl.faces.ravel(), minlength=len(atl.vertices)) > 20     # the caps' fan centres
    assert poles.sum() == 2
    # the chin's back folds a little (its radius grows there while it faces down): a few samples, at most
    assert np.count_nonzero(cnt > 1) <= 0.002 * np.count_nonzero(cnt)
    # charts (faces joined by shared vertices) no closer than the padding (3 texels; checked: 2)
    n_v = len(atl.vertices)
    f = atl.faces.astype(np.int64)
    adj = sp.coo_matrix((np.ones(f.size), (np.repeat(np.arange(len(f)), 3), f.ravel())), shape=(len(f), n_v)).tocsr()
    n, chart = connected_components(adj @ adj.T, directed=False)
    assert n >= 6
    covered = [_coverage(atl, TEXTURE, faces=chart == k) > 0 for k in range(n)]
    for k in range(n):
        grown = ndimage.binary_dilation(covered[k], iterations=2 * 2)            # 2 texels at 2 samples per texel
        for j in range(n):
            assert j == k or not np.any(grown & covered[j]), (k, j)
