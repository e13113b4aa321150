"""Bounded least-squares solvers against scipy.optimize.lsq_linear and closed forms."""
from __future__ import annotations

import gc
import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear
from scipy.sparse.linalg import svds

from imaging.compensation import (
    FrameCompensator,
    TransportOperator,
    objective,
    operator_for,
    solve,
    solve_per_projector,
    srgb_to_linear,
)
from imaging.compensation import solver
from imaging.compensation.synthetic import sample_image, synthetic_rig, synthetic_transport

SHAPE = (20, 24)


@pytest.fixture(scope="module")
def problem():
    rig = synthetic_rig(9, content_shape=SHAPE, radius=2, seed=3)
    per = synthetic_transport(rig, per_projector=True, scale=1 / 9)
    L = sum(per[1:], per[0])
    img = srgb_to_linear(sample_image(*SHAPE, channels=3, seed=1))
    target = 0.02 + 0.9 * img  # bright parts need more than the rig can give: bounds are active
    return L, per, target


def reference_objective(L, c):
    """Independent bounded least squares: SciPy's trust-region reflective lsq_linear, float64."""
    A = sp.csr_matrix(L, dtype=np.float64)
    b = np.asarray(c, dtype=np.float64).ravel()
    res = lsq_linear(A, b, bounds=(0, 1), method="trf", tol=1e-12, lsmr_tol=1e-12, max_iter=1000)
    assert res.status > 0
    return float(np.sum((A @ res.x - b) ** 2)), res.x


@pytest.fixture(scope="module")
def reference(problem):
    """``f(k)``: reference_objective of the whole rig's ``L`` and the target's channel ``k``, computed once
    a module (SciPy's solve takes about a second; six tests compare against the three channels)."""
    L, _, target = problem
    found: dict[int, float] = {}

    def f(k: int) -> float:
        if k not in found:
            found[k] = reference_objective(L, target[:, :, k])[0]
        return found[k]
    return f


@pytest.mark.parametrize("method", ["apg", "steepest", "lbfgsb"])
def test_matches_lsq_linear(problem, reference, method):
    L, _, target = problem
    c = target[:, :, 1]
    f_ref = reference(1)
    res = solve(L, c, method=method, tol=1e-9, gap_tol=0, pg_tol=0, max_iter=4000)
    assert res.x.shape == SHAPE and res.x.dtype == np.float32
    assert res.x.min() >= 0 and res.x.max() <= 1
    assert abs(res.objective - f_ref) <= 1e-3 * f_ref, (res.objective, f_ref, res.reason, res.iterations)
    assert res.objective == pytest.approx(objective(L, res.x, c), rel=1e-5)
    # bounds are really active at the optimum (otherwise this would be a plain least squares)
    assert np.mean((res.x <= 1e-4) | (res.x >= 1 - 1e-4)) > 0.05


def test_dual_bound_is_a_valid_certificate(problem, reference):
    L, _, target = problem
    c = target[:, :, 0]
    f_ref = reference(0)
    res = solve(L, c, tol=0, gap_tol=0.05, pg_tol=0, max_iter=3000)
    assert res.reason == "gap"
    assert 0 < res.lower_bound <= f_ref * (1 + 1e-6)
    assert (res.objective - f_ref) / f_ref <= 0.05 + 1e-9
    assert res.gap <= 0.05


def test_apg_needs_fewer_iterations_than_steepest(problem, reference):
    L, _, target = problem
    c = target[:, :, 2]
    goal = reference(2) * 1.001

    def first_at_goal(method: str, max_iter: int) -> int | None:
        """The first iteration whose objective is within the goal, in a run of up to ``max_iter`` (with
        every stopping rule off, a shorter run's history is the start of a longer one's)."""
        hist = solve(L, c, method=method, tol=0, gap_tol=0, pg_tol=0, max_iter=max_iter).history
        return next((k for k, f in enumerate(hist) if f <= goal), None)

    # APG reaches the goal in about 45 iterations here, steepest descent in about 130: 300 iterations
    # settle it (3,000 where they do not, as before), instead of running each method to 3,000 past its goal
    counts = {}
    for method in ("apg", "steepest"):
        counts[method] = first_at_goal(method, 300)
        if counts[method] is None:
            counts[method] = first_at_goal(method, 3000)
        assert counts[method] is not None, f"{method} did not reach the goal in 3000 iterations"
    assert counts["apg"] < counts["steepest"]


def test_channels_together_equal_channels_apart(problem, reference):
    L, _, target = problem
    both = solve(L, target, tol=1e-8, gap_tol=0, max_iter=3000)
    assert both.x.shape == (*SHAPE, 3)
    apart = [solve(L, target[:, :, k], tol=1e-8, gap_tol=0, max_iter=3000) for k in range(3)]
    assert both.objective == pytest.approx(sum(r.objective for r in apart), rel=2e-3)
    f_ref = sum(reference(k) for k in range(3))
    assert abs(both.objective - f_ref) <= 1e-3 * f_ref


def test_threads_give_the_same_iterates(problem):
    L, _, target = problem
    one = solve(TransportOperator(L, threads=1), target, tol=0, gap_tol=0, max_iter=30)
    two = solve(TransportOperator(L, threads=2), target, tol=0, gap_tol=0, max_iter=30)
    assert np.allclose(one.x, two.x, atol=1e-5)
    assert one.objective == pytest.approx(two.objective, rel=1e-5)


def test_lipschitz_bounds_the_largest_eigenvalue(problem):
    L, per, _ = problem
    for M in (L, per[0]):
        top = float(svds(sp.csr_matrix(M, dtype=np.float64), k=1, tol=1e-10, return_singular_vectors=False)[0]) ** 2
        op = TransportOperator(M)
        lip = op.lipschitz()
        assert top <= lip <= 1.06 * top
        assert op.lipschitz() is lip or op.lipschitz() == lip  # cached


def test_stopping_rules(problem):
    L, _, target = problem
    c = target[:, :, 0]
    assert solve(L, c, tol=0, gap_tol=0, pg_tol=0, max_iter=7).reason == "max_iter"
    assert solve(L, c, tol=0, gap_tol=0, pg_tol=0, max_iter=7).iterations == 7
    assert solve(L, c, tol=1e-3, gap_tol=0, pg_tol=0, max_iter=5000).reason == "objective"
    assert solve(L, c, tol=0, gap_tol=0, pg_tol=1e-2, max_iter=5000).reason == "gradient"
    # time limit with an injected clock that advances one second per reading
    ticks = iter(range(10_000))
    res = solve(L, c, tol=0, gap_tol=0, pg_tol=0, max_iter=5000, time_limit=10, clock=lambda: float(next(ticks)))
    assert res.reason == "time_limit" and res.iterations < 15
    assert not res.converged
    for method in ("steepest", "lbfgsb"):
        assert solve(L, c, method=method, tol=0, gap_tol=0, pg_tol=0, max_iter=3).iterations <= 3


def test_exact_target_is_reached():
    L = sp.identity(50, dtype=np.float32, format="csr") * 0.5
    c = np.linspace(0.05, 0.45, 50)
    res = solve(L, c, tol=0, gap_tol=1e-9, pg_tol=0, max_iter=200)
    assert np.allclose(res.x, 2 * c, atol=1e-5)
    assert res.converged


def test_warm_start_converges_faster(problem):
    L, _, target = problem
    frame0 = target[:, :, 1].copy()
    frame1 = frame0.copy()
    frame1[4:9, 6:11] = 0.8  # a small object moves into the picture
    first = solve(L, frame0, tol=1e-6)
    cold = solve(L, frame1, tol=1e-6)
    warm = solve(L, frame1, x0=first.x, tol=1e-6)
    assert warm.iterations < cold.iterations
    assert warm.objective <= cold.objective * 1.01
    # starting at the optimum: a handful of iterations
    again = solve(L, frame1, x0=cold.x, tol=1e-6)
    assert again.iterations <= 8


def test_warm_start_values_outside_the_bounds_are_clipped(problem):
    """A warm start's NaN reads 0, +inf 1, -inf 0; the rest is clipped into [0, 1] (the caller's
    array untouched): the solve is the one from the cleaned start, on CSR and on the stencil."""
    L, _, target = problem
    c = target[:, :, 1]
    x0 = np.clip(c, 0, 1).astype(np.float32)
    x0[0, :4] = [np.nan, np.inf, -np.inf, 1.5]
    x0[1, :2] = [-0.25, 0.5]
    clean = x0.copy()
    clean[0, :4] = [0.0, 1.0, 0.0, 1.0]
    clean[1, 0] = 0.0
    given = x0.copy()
    for storage in ("csr", "float32"):
        op = TransportOperator(L, storage=storage)
        dirty = solve(op, c, x0=x0, tol=0, gap_tol=0, pg_tol=0, max_iter=3)
        ref = solve(op, c, x0=clean, tol=0, gap_tol=0, pg_tol=0, max_iter=3)
        assert np.isfinite(dirty.objective)
        np.testing.assert_array_equal(dirty.x, ref.x)
    np.testing.assert_array_equal(x0, given)


def test_progress_reports_every_iteration(problem):
    L, _, target = problem
    seen = []
    res = solve(L, target[:, :, 0], tol=0, gap_tol=0, max_iter=12, progress=lambda k, f: seen.append((k, f)))
    assert [k for k, _ in seen] == list(range(1, 13))
    assert seen[-1][1] == res.objective and res.history[1:] == [f for _, f in seen]
    assert seen[-1][1] < seen[0][1]


def test_per_projector_baseline(problem):
    L, per, target = problem
    c = target[:, :, 0]
    base = solve_per_projector(per, c, tol=1e-8, gap_tol=0, max_iter=3000)
    assert len(base.xs) == 9 and base.iterations == sum(r.iterations for r in base.results)
    for Li, xi in zip(per[:3], base.xs[:3]):
        f_ref, _ = reference_objective(Li, c / 9)
        assert objective(Li, xi, c / 9) <= f_ref * 1.001 + 1e-12
    captured = sum(Li @ xi.reshape(-1) for Li, xi in zip(per, base.xs))
    assert captured.shape == (SHAPE[0] * SHAPE[1],)
    with pytest.raises(ValueError):
        solve_per_projector([], c)


def test_non_square_transport_needs_content_shape():
    rig = synthetic_rig(2, content_shape=(10, 12), camera_shape=(14, 15), radius=1, seed=0,
                        homography=np.array([[1.1, 0, 1], [0, 1.2, 1], [0, 0, 1.0]]))
    L = synthetic_transport(rig)
    c = np.full((14, 15), 0.3, dtype=np.float32)
    flat = solve(L, c, max_iter=50)
    assert flat.x.shape == (120,)
    shaped = solve(L, c, content_shape=(10, 12), max_iter=50)
    assert shaped.x.shape == (10, 12)
    with pytest.raises(ValueError):
        solve(L, np.zeros((10, 12)))
    with pytest.raises(ValueError):
        solve(L, c, content_shape=(11, 12))
    with pytest.raises(ValueError):
        solve(L, c, method="newton")
    with pytest.raises(ValueError):
        solve(L, c, x0=np.zeros(7))


def test_operator_cache_follows_the_matrix(problem):
    L, _, _ = problem
    M = L.copy()
    op = operator_for(M)
    assert operator_for(M) is op
    assert operator_for(op) is op
    key = id(M)
    del M, op
    gc.collect()
    assert key not in solver._OPERATORS


def test_objective_value_is_float64_accurate():
    rng = np.random.default_rng(0)
    L = sp.random(3000, 3000, density=0.002, random_state=1, dtype=np.float32, format="csr")
    x = rng.random(3000).astype(np.float32)
    c = rng.random(3000).astype(np.float32)
    exact = float(np.sum((L.astype(np.float64) @ x.astype(np.float64) - c) ** 2))
    assert math.isclose(objective(L, x, c), exact, rel_tol=1e-6)


def test_frame_compensator_warm_starts_and_keeps_deadlines(problem):
    L, _, target = problem
    frames = [target[:, :, 1].copy() for _ in range(3)]
    for k, f in enumerate(frames):
        f[4:9, 3 + 2 * k : 8 + 2 * k] = 0.8  # a small square moves right
    comp = FrameCompensator(L, iterations=5, first_iterations=200)
    first = comp(frames[0])
    assert first.iterations > 5
    later = [comp(f) for f in frames[1:]]
    assert all(r.iterations == 5 for r in later)
    # the warm start (previous solution + target change) beats a cold start with the same budget
    cold = solve(L, frames[2], max_iter=5, tol=0, gap_tol=0, pg_tol=0)
    assert later[-1].objective < cold.objective
    ticks = iter(range(10_000))
    timed = FrameCompensator(L, iterations=50, first_iterations=50, deadline=3, clock=lambda: float(next(ticks)))
    res = timed(frames[0])
    assert res.reason == "time_limit" and res.iterations < 10
    comp.reset()
    assert comp(frames[0]).iterations > 5
    with pytest.raises(ValueError):
        FrameCompensator(L, deadline=0)
