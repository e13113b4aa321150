"""The compiled stencil products against SciPy's CSR product of the same matrix: every row range,
both storages, one and three channels, outputs that are views into larger arrays, and light split
over several sinks (the fused sweep's halos)."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.compensation.stencil import StencilTransport

H, W = 23, 31


def _stencil(radius: int, storage: str, seed: int = 0) -> StencilTransport:
    """Random weights, zero where a window entry falls outside the grid (as measured ones are)."""
    rng = np.random.default_rng(seed)
    side = 2 * radius + 1
    w = rng.random((side * side, H, W), dtype=np.float32)
    for k in range(side * side):
        dy, dx = k // side - radius, k % side - radius
        ys, xs = np.arange(H)[:, None] + dy, np.arange(W)[None, :] + dx
        w[k][(ys < 0) | (ys >= H) | (xs < 0) | (xs >= W)] = 0
    if storage == "float32":
        return StencilTransport((H, W), radius, w)
    scale = 1.0 / 60000
    return StencilTransport((H, W), radius, np.rint(w / scale).astype(np.uint16), scale=scale)


@pytest.mark.parametrize("storage", ["float32", "uint16"])
@pytest.mark.parametrize("radius", [1, 2, 3])
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
    from coordinator.compensation import stencil_kernels as kernels
    from coordinator.compensation.solver import TransportOperator, solve
    from coordinator.compensation.synthetic import synthetic_rig, synthetic_transport

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
