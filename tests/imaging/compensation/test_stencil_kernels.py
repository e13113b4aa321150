"""The compiled stencil products against SciPy's CSR product of the same matrix: every row range,
both storages, one and three channels, outputs that are views into larger arrays, and light split
over several sinks (the fused sweep's halos); and the extraction of the weights from CSR, checked
against the weights the CSR matrix was made from."""
from __future__ import annotations

import numpy as np
import pytest

import scipy.sparse as sp

from imaging.compensation.stencil import StencilTransport, stencil_from_csr

H, W = 23, 31


def _stencil(radius: int, storage: str, seed: int = 0, shape: tuple[int, int] = (H, W)) -> StencilTransport:
    """Random weights, zero where a window entry falls outside the grid (as measured ones are)."""
    rng = np.random.default_rng(seed)
    side = 2 * radius + 1
    h, w_ = shape
    w = rng.random((side * side, h, w_), dtype=np.float32)
    for k in range(side * side):
        dy, dx = k // side - radius, k % side - radius
        ys, xs = np.arange(h)[:, None] + dy, np.arange(w_)[None, :] + dx
        w[k][(ys < 0) | (ys >= h) | (xs < 0) | (xs >= w_)] = 0
    if storage == "float32":
        return StencilTransport(shape, radius, w)
    scale = 1.0 / 60000
    return StencilTransport(shape, radius, np.rint(w / scale).astype(np.uint16), scale=scale)


WIDE = (9, 157)  # rows of several 64-pixel runs and a shorter last one


@pytest.mark.parametrize("radius", [1, 2, 3])
def test_extraction_gives_back_the_weights_the_matrix_was_made_of(radius):
    st = _stencil(radius, "float32", seed=radius, shape=WIDE)
    st.weights[:, 4, 70] = 0  # one window missing an entry (to_csr drops zeros): that run goes entry by entry
    L = st.to_csr()
    assert L.has_sorted_indices
    for threads in (1, 2, 3):
        got = stencil_from_csr(L, threads=threads)
        assert got is not None and got.radius == radius and got.grid == WIDE
        np.testing.assert_array_equal(got.weights, st.weights)
    q = stencil_from_csr(L, storage="uint16", threads=2)  # rounded to half a step of max / 65535
    assert q.scale == pytest.approx(float(L.data.max()) / 65535)
    err = np.abs(q.weights.astype(np.float64) * q.scale - st.weights)
    assert err.max() <= 0.5 * q.scale * (1 + 1e-6)
    np.testing.assert_array_equal(q.weights == 0, st.weights == 0)


def test_extraction_takes_any_csr_order_and_sums_duplicates():
    st = _stencil(2, "float32", seed=5, shape=WIDE)
    L = st.to_csr()
    rng = np.random.default_rng(0)
    split = 5 * WIDE[1] + 80  # this row's entries come as two halves each (exact in float32)
    indptr, indices, data = [0], [], []
    for i in range(L.shape[0]):
        cols, vals = L.indices[L.indptr[i] : L.indptr[i + 1]], L.data[L.indptr[i] : L.indptr[i + 1]]
        if i == split:
            cols, vals = np.concatenate([cols, cols]), np.concatenate([vals / 2, vals / 2])
        order = rng.permutation(cols.size)
        indices.append(cols[order])
        data.append(vals[order])
        indptr.append(indptr[-1] + cols.size)
    M = sp.csr_matrix((np.concatenate(data), np.concatenate(indices), np.array(indptr)), shape=L.shape)
    assert not M.has_canonical_format and M.nnz == L.nnz + 25
    got = stencil_from_csr(M, threads=2)
    np.testing.assert_array_equal(got.weights, st.weights)


def test_extraction_refuses_an_entry_outside_its_window_anywhere():
    st = _stencil(2, "float32", seed=6, shape=WIDE)
    L = st.to_csr()
    row = 4 * WIDE[1] + 100  # interior, in the middle of a run of full windows
    for bad in (row - 3, row + 3 * WIDE[1], row - WIDE[1] - 3):  # dx = 3, dy = -3, a wrap of dy = 1, dx = -3
        M = L.tolil()
        M[row, bad] = 0.5
        M[row, M.rows[row][0]] = 0  # the window keeps its count of entries
        M = M.tocsr()
        M.eliminate_zeros()
        assert stencil_from_csr(M) is None
    negative = L.copy()
    negative.data[negative.indptr[row]] = -0.1
    assert stencil_from_csr(negative) is not None  # float32 holds any sign
    assert stencil_from_csr(negative, storage="uint16") is None


@pytest.mark.parametrize("storage", ["float32", "uint16"])
@pytest.mark.parametrize("radius", [1, 2, 3, 4])  # offsets applied in groups of 5: 3, 5, 5 + 2, 5 + 4
@pytest.mark.parametrize("channels", [1, 3])
def test_both_products_are_the_csr_products_on_any_row_range(storage, radius, channels):
    st = _stencil(radius, storage, seed=radius)
    L = st.to_csr().astype(np.float64)
    rng = np.random.default_rng(7)
    x = rng.random((channels, H, W), dtype=np.float32)
    v = rng.random((channels, H, W), dtype=np.float32)
    want_fwd = np.stack([(L @ x[c].reshape(-1)).reshape(H, W) for c in range(channels)])
    want_adj = np.stack([(L.T @ v[c].reshape(-1)).reshape(H, W) for c in range(channels)])
    for y0, y1 in [(0, H), (0, 1), (5, 12), (H - radius - 1, H), (radius, H - radius)]:
        big = np.full((channels, H + 4, W), np.nan, dtype=np.float32)  # the output is a view of rows 2.. of it
        out = big[:, 2 : 2 + y1 - y0]
        st.forward_rows(x, out, y0, y1)
        np.testing.assert_allclose(out, want_fwd[:, y0:y1], rtol=2e-6, atol=2e-6)
        assert np.isnan(big[:, :2]).all() and np.isnan(big[:, 2 + y1 - y0 :]).all(), "wrote outside its rows"
        st.adjoint_rows(v, out, y0, y1)
        np.testing.assert_allclose(out, want_adj[:, y0:y1], rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("storage", ["float32", "uint16"])
def test_a_bands_light_splits_over_sinks_and_nothing_lands_twice(storage):
    st = _stencil(2, storage, seed=3)
    L = st.to_csr().astype(np.float64)
    x = np.random.default_rng(4).random((2, H, W), dtype=np.float32)
    y0, y1 = 8, 14  # the band's content rows; its light reaches rows 6..15
    only = np.zeros_like(x)
    only[:, y0:y1] = x[:, y0:y1]
    want = np.stack([(L @ only[c].reshape(-1)).reshape(H, W) for c in range(2)])
    sinks = [(6, 8, np.zeros((2, 2, W), np.float32)), (8, 14, np.zeros((2, 6, W), np.float32)),
             (14, 20, np.zeros((2, 6, W), np.float32))]
    st.scatter_band(x[:, y0:y1], y0, y1, sinks)
    got = np.zeros_like(want)
    for r0, r1, view in sinks:
        got[:, r0:r1] += view
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=2e-6)
    assert not want[:, :6].any() and not want[:, 16:].any()


@pytest.mark.parametrize("storage", ["float32", "uint16"])
def test_building_the_operator_compiles_what_a_solve_needs(storage):
    """After :class:`TransportOperator` is built, solving (grey and RGB) and both products compile
    nothing more: a solve's time budget or a video frame's deadline is not spent on the compiler."""
    from imaging.compensation import stencil_kernels as kernels
    from imaging.compensation.solver import TransportOperator, solve
    from imaging.compensation.synthetic import synthetic_rig, synthetic_transport

    L = synthetic_transport(synthetic_rig(4, content_shape=(24, 32), radius=2, seed=1), scale=0.25,
                            footprint_samples=1, workers=1)
    op = TransportOperator(L, threads=2, storage=storage)
    compiled = {f.__name__: list(f.signatures) for f in (kernels.adjoint_rows, kernels.scatter_rows, kernels.sweep_rows)}
    target = np.random.default_rng(0).random((24, 32, 3), dtype=np.float32) * 0.5
    solve(op, target, max_iter=5, threads=2)
    solve(op, target[:, :, 0], max_iter=5, threads=2)
    op.matvec(np.ones(L.shape[1], np.float32))
    op.rmatvec(np.ones(L.shape[0], np.float32))
    assert {f.__name__: list(f.signatures) for f in (kernels.adjoint_rows, kernels.scatter_rows,
                                                     kernels.sweep_rows)} == compiled


@pytest.mark.parametrize("beta", [0.0, 0.7])
def test_a_rows_update_is_the_projected_step_in_float64(beta):
    """:func:`update_row` against NumPy in float64: the clipped step from the extrapolated point,
    the light it scatters, and its three sums (the first iteration, beta 0, reads no x_{k-1})."""
    from imaging.compensation.stencil_kernels import update_row

    rng = np.random.default_rng(3)
    n = 1037   # not a multiple of any vector width
    g = rng.standard_normal(n).astype(np.float32)
    xk, xprev = rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)
    xprev[::7] = xk[::7]    # some steps of zero momentum
    scale, step = np.float32(0.37), np.float32(0.6)
    xo, light = xprev.copy(), np.empty(n, np.float32)
    sums = update_row(g, xk, xo, light, scale, step, np.float32(beta))

    g64, xk64 = g.astype(np.float64) * 0.37, xk.astype(np.float64)
    y = xk64 + beta * (xk64 - xprev.astype(np.float64))
    want = np.clip(y - 0.6 * g64, 0.0, 1.0)
    np.testing.assert_allclose(xo, want, rtol=0, atol=2e-6)
    np.testing.assert_allclose(light, want * 0.37, rtol=0, atol=1e-6)
    d = y - want
    np.testing.assert_allclose(sums, (np.minimum(g64, 0).sum(), d @ d, d @ (want - xk64)), rtol=1e-5, atol=1e-5)
    assert (xo == 0).any() and (xo == 1).any()   # both bounds were hit
