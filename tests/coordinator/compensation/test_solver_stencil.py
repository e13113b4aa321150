"""The stencil storage of L and the fused APG sweep, against SciPy's CSR products and lsq_linear."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from imaging.compensation.solver import TransportOperator, objective, solve
from imaging.compensation.stencil import stencil_from_csr
from imaging.compensation.synthetic import sample_image, synthetic_rig, synthetic_transport

SHAPE = (26, 30)


def rig_transport(shape=SHAPE, radius=2, n=9, seed=3):
    return synthetic_transport(synthetic_rig(n, content_shape=shape, radius=radius, seed=seed), scale=1 / n)


@pytest.fixture(scope="module")
def L():
    return rig_transport()


@pytest.fixture(scope="module")
def target():
    return (0.02 + 0.9 * sample_image(*SHAPE, channels=3, seed=1)).astype(np.float32)


@pytest.mark.parametrize("radius", [1, 2, 3])
def test_float32_storage_is_the_matrix_itself(radius):
    L = rig_transport(radius=radius)
    st = stencil_from_csr(L)
    assert st is not None and st.grid == SHAPE and st.radius == radius
    assert st.weights.shape == ((2 * radius + 1) ** 2, *SHAPE) and st.weights.dtype == np.float32
    assert (st.to_csr() != L).nnz == 0  # every entry, bit for bit, and nothing else
    rng = np.random.default_rng(0)
    x = rng.random((L.shape[1], 3), dtype=np.float32)
    for threads in (1, 2, 3):
        op = TransportOperator(L, threads=threads)
        assert op.storage == "float32"
        np.testing.assert_allclose(op.matvec(x), L.astype(np.float64) @ x, rtol=0, atol=2e-6)
        np.testing.assert_allclose(op.rmatvec(x), L.T.astype(np.float64) @ x, rtol=0, atol=2e-6)
        np.testing.assert_allclose(op.matvec(x[:, 1]), L.astype(np.float64) @ x[:, 1], rtol=0, atol=2e-6)


def test_uint16_storage_rounds_each_entry_to_half_a_step(L):
    st = stencil_from_csr(L, storage="uint16")
    assert st.weights.dtype == np.uint16 and st.scale == pytest.approx(L.data.max() / 65535)
    err = abs(st.to_csr().astype(np.float64) - L.astype(np.float64))
    assert err.max() <= 0.5 * st.scale * (1 + 1e-6)
    op = TransportOperator(L, storage="uint16")
    x = np.random.default_rng(1).random(L.shape[1], dtype=np.float32)
    # 25 entries per row, each off by at most half a step, times x <= 1
    assert np.abs(op.matvec(x) - L.astype(np.float64) @ x).max() <= 25 * 0.5 * st.scale + 1e-6
    assert op.storage_bytes * 2 == TransportOperator(L, storage="float32").storage_bytes


def test_other_structures_stay_in_csr():
    random = sp.random(900, 900, density=0.01, random_state=1, dtype=np.float32, format="csr")
    assert TransportOperator(random).storage == "csr"
    with pytest.raises(ValueError, match="structure"):
        TransportOperator(random, storage="float32")
    # content and camera on different grids (a homography between them)
    rig = synthetic_rig(2, content_shape=(10, 12), camera_shape=(14, 15), radius=1, seed=0,
                        homography=np.array([[1.1, 0, 1], [0, 1.2, 1], [0, 0, 1.0]]))
    assert TransportOperator(synthetic_transport(rig)).storage == "csr"
    # one entry that wraps from the start of a row to the end of the previous one
    L = rig_transport().tolil()
    L[2 * SHAPE[1] - 1, 2 * SHAPE[1]] = 0.01
    assert stencil_from_csr(L.tocsr()) is None
    with pytest.raises(ValueError):
        TransportOperator(rig_transport(), storage="float16")


def test_the_ridge_stack_keeps_the_stencil(L):
    d = np.float32(0.3)
    S = sp.vstack([L, sp.identity(L.shape[1], dtype=np.float32, format="csr") * d], format="csr")
    op = TransportOperator(S, threads=2)
    assert op.storage == "float32" and op.stencil.tail is not None
    rng = np.random.default_rng(2)
    x = rng.random((L.shape[1], 2), dtype=np.float32)
    v = rng.random((S.shape[0], 2), dtype=np.float32)
    np.testing.assert_allclose(op.matvec(x), S.astype(np.float64) @ x, atol=2e-6)
    np.testing.assert_allclose(op.rmatvec(v), S.T.astype(np.float64) @ v, atol=2e-6)
    # the solve runs the two-product APG over stencil bands plus the diagonal: the CSR iterates
    goal = np.concatenate([rng.random(L.shape[0], dtype=np.float32), d * rng.random(L.shape[1], dtype=np.float32)])
    ref = solve(TransportOperator(S, storage="csr"), goal, tol=0, gap_tol=0, pg_tol=0, max_iter=30)
    res = solve(op, goal, tol=0, gap_tol=0, pg_tol=0, max_iter=30)
    np.testing.assert_allclose(res.history, ref.history, rtol=2e-5)


@pytest.mark.parametrize("threads", [1, 2, 3, 5])
def test_fused_sweep_follows_the_csr_iterates(L, target, threads):
    """Same step, restarts and stopping rules as the CSR APG: the histories agree to float32 rounding
    (threads split the rows; 5 leaves some ranges barely wider than the stencil)."""
    for c in (target[:, :, 0], target):
        x0 = np.clip(c, 0, 1)  # the same start for both (the stencil's default start is its own)
        ref = solve(TransportOperator(L, storage="csr"), c, x0=x0, tol=0, gap_tol=0, pg_tol=0, max_iter=40)
        res = solve(TransportOperator(L, threads=threads), c, x0=x0, tol=0, gap_tol=0, pg_tol=0, max_iter=40)
        np.testing.assert_allclose(res.history, ref.history, rtol=2e-5)
        np.testing.assert_allclose(res.x, ref.x, atol=2e-5)
        assert res.lower_bound == pytest.approx(ref.lower_bound, rel=1e-4)


@pytest.fixture(scope="module")
def reference(L, target):
    """Independent bounded least squares for the green channel: SciPy's lsq_linear (trust region reflective, float64)."""
    c = target[:, :, 1]
    A = sp.csr_matrix(L, dtype=np.float64)
    ref = lsq_linear(A, c.astype(np.float64).ravel(), bounds=(0, 1), method="trf", tol=1e-12, lsmr_tol=1e-12,
                     max_iter=1000)
    return c, float(np.sum((A @ ref.x - c.ravel()) ** 2))


@pytest.mark.parametrize("storage", ["float32", "uint16"])
def test_matches_lsq_linear(L, reference, storage):
    c, f_ref = reference
    op = TransportOperator(L, storage=storage)
    res = solve(op, c, tol=1e-9, gap_tol=0, pg_tol=0, max_iter=4000)
    f = objective(TransportOperator(L, storage="csr"), res.x, c)  # through the exact matrix
    assert abs(f - f_ref) <= 1e-3 * f_ref, (f, f_ref, res.reason)
    assert np.mean((res.x <= 1e-4) | (res.x >= 1 - 1e-4)) > 0.05  # the bounds are active


def test_step_bound_stops_early_with_the_same_value(L):
    full = TransportOperator(L, storage="csr")
    quick = TransportOperator(L)
    assert quick.lipschitz() == pytest.approx(full.lipschitz(early_exit=False), rel=1e-6)
    assert quick.lipschitz_info["schur_bound"] == quick.lipschitz()


def test_an_iteration_moves_fewer_bytes(L):
    csr = TransportOperator(L, storage="csr")
    f32, u16 = TransportOperator(L), TransportOperator(L, storage="uint16")
    m, n = L.shape
    vectors = 4 * (5 * n + 6 * m)
    assert csr.bytes_per_iteration() == 2 * (L.data.nbytes + L.indices.nbytes + L.indptr.nbytes) + vectors
    assert f32.bytes_per_iteration() == 4 * 25 * n + vectors  # the fused sweep reads the weights once
    assert u16.bytes_per_iteration() == 2 * 25 * n + vectors
    f32.fused = False
    assert f32.bytes_per_iteration() == 2 * 4 * 25 * n + vectors


def test_solves_share_one_set_of_worker_threads(L, target, monkeypatch):
    """A video solves every frame: once the workers exist, a solve starts no thread."""
    import threading

    op = TransportOperator(L, threads=2)
    first = solve(op, target, max_iter=5, tol=0, threads=2)
    started = []
    real_start = threading.Thread.start
    monkeypatch.setattr(threading.Thread, "start", lambda self: (started.append(self.name), real_start(self))[1])
    again = solve(op, target, max_iter=5, tol=0, threads=2)
    monkeypatch.undo()
    assert started == []
    np.testing.assert_array_equal(again.x, first.x)


def test_solves_at_once_from_several_threads_give_their_own_results(L, target):
    """The shared workers only run the solver's own row tasks: concurrent solves neither deadlock nor mix."""
    from concurrent.futures import ThreadPoolExecutor

    op = TransportOperator(L, threads=2)
    targets = [np.clip(target * s, 0, 1).astype(np.float32) for s in (0.6, 0.8, 1.0, 1.2)]
    alone = [solve(op, t, max_iter=8, tol=0, threads=2).x for t in targets]
    with ThreadPoolExecutor(4) as callers:
        together = list(callers.map(lambda t: solve(op, t, max_iter=8, tol=0, threads=2).x, targets))
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a, b)
