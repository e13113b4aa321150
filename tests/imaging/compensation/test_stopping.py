"""The solver's stopping rules: the extrapolated rule against a closed form and against lsq_linear."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from imaging.compensation import TransportOperator, solve, srgb_to_linear
from imaging.compensation.stopping import WINDOW, Stopper
from imaging.compensation.synthetic import sample_image, synthetic_rig, synthetic_transport


def _stopper(**rules) -> Stopper:
    base = {"tol": 0.0, "gap_tol": 0.0, "pg_tol": 0.0, "max_iter": 10_000, "time_limit": None, "clock": lambda: 0.0, "start": 0.0}
    return Stopper(**{**base, **rules})


def test_remaining_is_exact_on_a_geometric_sequence():
    # f_k = f* + A q^k: the decreases over two windows of w have ratio q^w, and d1 q^w / (1 - q^w) = A q^k
    fstar, a, q = 2.0, 5.0, 0.8
    s = _stopper()
    for k in range(40):
        s.history.append(fstar + a * q**k)
        if k >= 2 * WINDOW:
            assert s.remaining() == pytest.approx(a * q**k, rel=1e-9)


def test_remaining_is_unknown_until_two_decreasing_windows():
    s = _stopper()
    s.history.extend([1.0 + 0.5**k for k in range(2 * WINDOW)])  # one value short of two windows
    assert math.isinf(s.remaining())
    s.history.append(1.0 + 0.5 ** (2 * WINDOW))
    assert math.isfinite(s.remaining())
    s.history[:] = [10.0 - k for k in range(2 * WINDOW + 1)]  # linear: d1 == d0, no geometric limit
    assert math.isinf(s.remaining())
    s.history[:] = [1.0 + 0.01 * k for k in range(2 * WINDOW + 1)]  # rising
    assert math.isinf(s.remaining())


def _geometric(a: float) -> list[float]:
    return [1.0 + a * 0.5**k for k in range(2 * WINDOW + 1)]


def test_extrapolated_needs_a_small_last_window():
    s = _stopper(est_tol=0.01)
    s.history.extend(_geometric(5.0))  # 0.5 % left, but the last window still gained 15 %
    f = s.history[-1]
    assert s.remaining() <= 0.01 * f and s.history[-1 - WINDOW] - f > 0.01 * f
    assert s.check(2 * WINDOW, f, 1.0) is None
    s.history[:] = _geometric(0.05)  # both small
    assert s.check(2 * WINDOW, s.history[-1], 1.0) == "extrapolated"
    off = _stopper(est_tol=0.0)  # 0 disables the rule
    off.history.extend(_geometric(0.05))
    assert off.check(2 * WINDOW, off.history[-1], 1.0) is None


@pytest.fixture(scope="module")
def problems():
    """Two shared-grid rigs (the stencil storage and its one-sweep APG) with an lsq_linear reference each."""
    out = []
    for shape, n, seed in (((48, 64), 9, 1), ((60, 80), 25, 2)):
        L = synthetic_transport(synthetic_rig(n, content_shape=shape, radius=2, seed=seed), scale=1 / n)
        c = 0.02 + 0.9 * srgb_to_linear(sample_image(*shape, channels=1, seed=seed))  # bounds are active
        A, b = sp.csr_matrix(L, dtype=np.float64), c.ravel().astype(np.float64)
        # tol 1e-9: the optimum's objective agrees with tol 1e-12's to 2e-10 (relative) in under half the time
        ref = lsq_linear(A, b, bounds=(0, 1), method="trf", tol=1e-9, lsmr_tol=1e-9, max_iter=1000)
        out.append((TransportOperator(L), c, float(np.sum((A @ ref.x - b) ** 2))))
    return out


@pytest.mark.parametrize("method, factor", [("apg", 1.5), ("steepest", 2.5)])
def test_extrapolated_rule_stops_near_the_optimum(problems, method, factor):
    for op, c, fref in problems:
        assert op.storage == "float32"
        runs = {est: solve(op, c, method=method, tol=0, gap_tol=0, pg_tol=0, est_tol=est, max_iter=5000) for est in (0.005, 0.001)}
        for est, r in runs.items():
            gap = (r.objective - fref) / fref
            assert r.reason == "extrapolated" and r.converged
            assert -1e-4 <= gap <= factor * est, (method, est, r.iterations, gap)
        assert runs[0.001].iterations > runs[0.005].iterations  # a tighter estimate takes longer
