"""The Lipschitz envelope of a surface on a grid: the largest function under it whose slope is bounded.

``lower_envelope(f, slope)`` is ``g(x) = min_y f(y) + slope * d(x, y)``, the largest ``g <= f``
with ``|g(x) - g(y)| <= slope * d(x, y)``; ``upper_envelope`` is its mirror (the smallest ``g >=
f``). ``d`` is the 8-neighbour chamfer distance with steps 1 and sqrt(2), which in the plane is
``max(|dx|, |dy|) + (sqrt(2) - 1) min(|dx|, |dy|)`` (within 8 % of the Euclidean distance).

Computed with two sweeps (Borgefors' chamfer distance transform, in min-plus form): down the rows,
each row takes the row above plus one vertical or diagonal step, then is swept left and right in
one vectorised step (``j + cummin(g - j)``); then up the rows the same way. A shortest chamfer path
is monotone in both coordinates, so the two sweeps are exact, not an approximation of ``d``;
:func:`brute_force_lower_envelope` is the O(n^2) definition the tests hold them to.

Non-finite entries of ``f`` (``+inf``) constrain nothing; the envelope passes through them.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["lower_envelope", "upper_envelope", "brute_force_lower_envelope", "chamfer_distance"]

_DIAG = math.sqrt(2.0)


def _row_sweep(row: np.ndarray, step: float, ramp: np.ndarray) -> np.ndarray:
    """``row`` after propagating ``+step`` per column both ways: ``min_k row[k] + step |j - k|``."""
    right = np.minimum.accumulate(row - ramp) + ramp
    rev = row[::-1]
    left = (np.minimum.accumulate(rev - ramp) + ramp)[::-1]
    return np.minimum(right, left)


def _sweep(g: np.ndarray, slope: float) -> None:
    h, w = g.shape
    ramp = slope * np.arange(w, dtype=np.float64)
    diag = slope * _DIAG
    g[0] = _row_sweep(g[0], slope, ramp)
    for i in range(1, h):
        prev = g[i - 1]
        cand = prev + slope
        if w > 1:
            np.minimum(cand[1:], prev[:-1] + diag, out=cand[1:])
            np.minimum(cand[:-1], prev[1:] + diag, out=cand[:-1])
        np.minimum(g[i], cand, out=g[i])
        g[i] = _row_sweep(g[i], slope, ramp)


def lower_envelope(f: np.ndarray, slope: float) -> np.ndarray:
    """``(h, w) float64``: ``min_y f(y) + slope * d(x, y)`` (see the module docstring).

    Parameters
    ----------
    f : (h, w) float
        The surface; ``+inf`` where it sets no bound.
    slope : float >= 0
        The largest change per grid step.
    """
    a = np.array(f, np.float64)
    if a.ndim != 2:
        raise ValueError(f"the envelope needs an (h, w) surface, got {a.shape}")
    if not slope >= 0 or not math.isfinite(slope):
        raise ValueError(f"slope must be finite and >= 0, got {slope!r}")
    a[np.isnan(a)] = np.inf
    _sweep(a, slope)
    b = a[::-1].copy()
    _sweep(b, slope)
    return np.ascontiguousarray(b[::-1])


def upper_envelope(f: np.ndarray, slope: float) -> np.ndarray:
    """``(h, w) float64``: ``max_y f(y) - slope * d(x, y)``, the smallest slope-bounded surface above ``f``
    (``-inf`` entries set no bound)."""
    a = np.array(f, np.float64)
    a[np.isnan(a)] = -np.inf
    return -lower_envelope(-a, slope)


def chamfer_distance(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """The 8-neighbour chamfer distance of offsets ``(dx, dy)``."""
    ax, ay = np.abs(dx), np.abs(dy)
    return np.maximum(ax, ay) + (_DIAG - 1.0) * np.minimum(ax, ay)


def brute_force_lower_envelope(f: np.ndarray, slope: float) -> np.ndarray:
    """The definition, ``O(n^2)`` in the grid's pixels: for tests on small grids only."""
    a = np.array(f, np.float64)
    h, w = a.shape
    ys, xs = np.mgrid[0:h, 0:w]
    src = np.isfinite(a)
    sy, sx, sv = ys[src], xs[src], a[src]
    out = np.full((h, w), np.inf)
    if not len(sv):
        return out
    for i in range(h):
        for j in range(w):
            out[i, j] = np.min(sv + slope * chamfer_distance(sx - j, sy - i))
    return out
