"""When an iterative solve of ``min ||L x - c||^2, 0 <= x <= 1`` stops (:mod:`.solver`'s rules).

``"gap"``
    Certified: a Lagrangian dual bound ``D <= min`` (:func:`dual_bound`) comes for free from each
    residual and gradient; stop when ``(objective - D) / D <= gap_tol``.
``"objective"``
    The objective fell by less than ``5 * tol`` (relative) over the last 5 iterations.
``"extrapolated"``
    The objective fell by at most ``est_tol`` (relative) over the last 5 iterations, *and* its
    remaining decrease, extrapolated from the last two windows of 5 iterations, is at most
    ``est_tol`` times the objective. FISTA with restart converges nearly geometrically on a blur:
    with ``d0``, ``d1`` the decreases over the two windows and ``q = d1 / d0 < 1``, what remains
    is about ``d1 q / (1 - q)`` (exact for a geometric sequence). The first condition guards the
    start, where a fast first window makes ``q`` small and the extrapolation optimistic (alone it
    stopped projected steepest descent after 10 iterations, 12 % above the optimum). Unlike
    ``"objective"``, which stops at the same decrease per iteration however slowly the solve
    converges, this rule waits longer when convergence is slow (``q`` near 1). At 2592x1944 with
    25 projectors, ``est_tol = 0.005`` stopped five targets 0.57-0.70 % above the optimum (after
    26-53 iterations), where ``tol = 1e-3`` (its first condition alone) stopped them 0.61-1.31 %
    above it. It is an estimate, not a certificate: on the tests' two small rigs it stopped APG
    within 1.4 ``est_tol`` and steepest descent within 2 ``est_tol`` of the optimum, but on a
    20x24 rig APG with ``est_tol = 0.001`` stopped 3.3 ``est_tol`` above it. Where a guarantee
    matters, ``gap_tol`` gives one.
``"gradient"``
    The projected-gradient step's norm fell below ``pg_tol`` times its first value.
``"optimal"``: zero residual. ``"max_iter"`` / ``"time_limit"``: the budget is spent.

A tolerance of 0 disables its rule.
"""
from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["CONVERGED", "Stopper", "WINDOW", "dual_bound"]

#: the reasons that count as converged (the others are a spent budget)
CONVERGED = ("gap", "objective", "extrapolated", "gradient", "optimal")

#: iterations per window of the "objective" and "extrapolated" rules
WINDOW = 5


class Stopper:
    """The shared stopping rules; ``check`` returns the reason to stop, or None.

    ``history`` holds the objective at the start and after every iteration (the solvers append to it).
    """

    def __init__(self, *, tol: float, gap_tol: float, pg_tol: float, max_iter: int,
                 time_limit: float | None, clock: Callable[[], float], start: float, est_tol: float = 0.0) -> None:
        self.tol, self.gap_tol, self.pg_tol, self.est_tol = tol, gap_tol, pg_tol, est_tol
        self.max_iter, self.time_limit, self.clock, self.start = max_iter, time_limit, clock, start
        self.history: list[float] = []
        self.lower = -math.inf
        self.pg0: float | None = None

    def bound(self, value: float) -> None:
        if value > self.lower:
            self.lower = value

    def gap(self, f: float) -> float:
        return (f - self.lower) / self.lower if self.lower > 0 else math.inf

    def remaining(self) -> float:
        """The extrapolated remaining decrease of the objective (``inf`` until it can be told: two
        windows of history, both decreasing, the later by less)."""
        h, w = self.history, WINDOW
        if len(h) < 2 * w + 1:
            return math.inf
        d0, d1 = h[-1 - 2 * w] - h[-1 - w], h[-1 - w] - h[-1]
        if d0 <= 0 or d1 <= 0 or d1 >= d0:
            return math.inf
        q = d1 / d0
        return d1 * q / (1.0 - q)

    def check(self, k: int, f: float, pg: float) -> str | None:
        """After iteration ``k`` (1-based) with objective ``f`` (already in ``history``) and
        projected-gradient norm ``pg``."""
        h = self.history
        if f <= 0:
            return "optimal"
        if self.gap_tol > 0 and self.gap(f) <= self.gap_tol:
            return "gap"
        if self.pg0 is None:
            self.pg0 = pg
        if self.pg_tol > 0 and self.pg0 and pg <= self.pg_tol * self.pg0:
            return "gradient"
        w = WINDOW
        if self.tol > 0 and len(h) > w and h[-1 - w] - f <= w * self.tol * f:
            return "objective"
        if self.est_tol > 0 and len(h) > w and h[-1 - w] - f <= self.est_tol * f and self.remaining() <= self.est_tol * f:
            return "extrapolated"
        if k >= self.max_iter:
            return "max_iter"
        if self.time_limit is not None and self.clock() - self.start >= self.time_limit:
            return "time_limit"
        return None


def dual_bound(rr: float, rc: float, gneg: float) -> float:
    """Best Lagrangian dual value of ``min ||Lx-c||^2, 0<=x<=1`` along the ray ``alpha * r``.

    With ``g = L^T r``: ``D(a r) = -a^2 rr - 2 a rc + 2 a gneg`` (``gneg = sum min(0, g)``),
    maximised over ``a >= 0``; any value is a lower bound of the minimum.
    """
    if rr <= 0:
        return 0.0
    a = (gneg - rc) / rr
    return a * a * rr if a > 0 else 0.0
