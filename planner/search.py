"""Greedy forward selection with swap refinement over an :class:`~planner.evaluate.Evaluator`.

Each step adds the candidate that leaves the least surface area lit by fewer
than ``k`` projectors and, among those, the lowest proxy (coverage first: a
point nobody lights cannot be helped by a low drop elsewhere). The proxy after
each step is the curve an operator reads against the budget. At the budget,
swaps (one member out, one candidate in) are tried until none improves the
same key, at most ``max_passes`` rounds.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner.evaluate import Evaluator


@dataclass
class Plan:
    """What the search found.

    Attributes
    ----------
    chosen : list of int
        Candidate indices, in the order the greedy pass took them (then swapped in place).
    curve : list of float
        The proxy of the greedy prefix of each size 1..budget.
    uncovered_curve : list of float
        mm^2 lit by fewer than k, per prefix size.
    value, uncovered : float
        Of ``chosen`` after the swaps.
    swaps : int
    """

    chosen: list[int]
    curve: list[float]
    uncovered_curve: list[float]
    value: float
    uncovered: float
    swaps: int = 0
    log: list[str] = field(default_factory=list)


def _best(uncovered: np.ndarray, values: np.ndarray, allowed: np.ndarray) -> int:
    u = np.where(allowed, uncovered, np.inf)
    v = np.where(allowed & (u <= u.min() + 1e-6), values, np.inf)
    return int(np.argmin(v))


def plan(ev: Evaluator, budget: int, *, k: int = 1, max_passes: int = 3, progress: Callable[[str], None] | None = None) -> Plan:
    """Choose ``budget`` of the evaluator's candidates.

    Raises
    ------
    ValueError
        When the budget exceeds the candidates or is not positive.
    """
    if not 1 <= budget <= ev.candidates:
        raise ValueError(f"budget must be 1..{ev.candidates} (the candidates), got {budget}")
    if k < 1:
        raise ValueError("k must be at least 1")
    chosen: list[int] = []
    curve, unc_curve = [], []
    for step in range(budget):
        allowed = np.ones(ev.candidates, bool)
        allowed[chosen] = False
        unc = ev.uncovered_with_each(chosen, k)
        vals = ev.with_each(chosen)
        c = _best(unc, vals, allowed)
        chosen.append(c)
        curve.append(float(vals[c]))
        unc_curve.append(float(unc[c]))
        if progress is not None:
            progress(f"greedy {step + 1}/{budget}: {ev.sources[c].name} -> {ev.proxy} {vals[c]:.4g}")
    best_key = (unc_curve[-1], curve[-1])
    swaps = 0
    log = []
    for _ in range(max_passes):
        improved = False
        for pos in range(len(chosen)):
            rest = chosen[:pos] + chosen[pos + 1:]
            allowed = np.ones(ev.candidates, bool)
            allowed[chosen] = False
            if not allowed.any():
                break
            unc = ev.uncovered_with_each(rest, k)
            vals = ev.with_each(rest)
            c = _best(unc, vals, allowed)
            key = (float(unc[c]), float(vals[c]))
            if key[0] < best_key[0] - 1e-6 or (key[0] <= best_key[0] + 1e-6 and key[1] < best_key[1] - 1e-9):
                log.append(f"swap {ev.sources[chosen[pos]].name} -> {ev.sources[c].name}: {best_key[1]:.4g} -> {key[1]:.4g}")
                chosen[pos] = c
                best_key = key
                swaps += 1
                improved = True
        if progress is not None:
            progress(f"swap pass: {swaps} swaps so far, {ev.proxy} {best_key[1]:.4g}")
        if not improved:
            break
    return Plan(chosen, curve, unc_curve, best_key[1], best_key[0], swaps, log)


def knee(curve: list[float], span: float, *, fraction: float = 0.05) -> int | None:
    """The projector count after which one more improves the proxy by less than ``fraction`` x ``span``.

    ``curve[i]`` is the proxy with i + 1 projectors. Returns the smallest count
    n from which every further step improves by less: ``curve[m - 1] - curve[m]
    < fraction * span`` for all m >= n (None when the last step still improves by more).
    """
    n = len(curve)
    while n > 1 and curve[n - 2] - curve[n - 1] < fraction * span:
        n -= 1
    return n if n < len(curve) else None
