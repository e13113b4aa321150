"""The APG iteration of :mod:`.solver` in one sweep over the stencil weights per iteration.

The plain iteration (``_apg`` in :mod:`.solver`) reads ``L`` twice: ``g = L^T r`` for every
content pixel, then ``L x_{k+1}`` for every camera pixel, with a global reduction (the restart
test) in between. With the stencil storage (:mod:`.stencil`) both products can read the same
weight rows: the adjoint of a content row gives that row's gradient, the update its ``x_{k+1}``,
and the forward product *from* that row (its light scattered onto camera rows ``[y - R, y + R]``)
reads the same weight row again while it is in the first-level cache, so ``L`` streams from memory
once per iteration. What stands in the way is the momentum: the residual at ``y_{k+1}`` needs
``beta_{k+1}``, known only after the whole sweep. So the sweep keeps ``Lx_k`` and ``Lx_{k-1}`` and
assembles ``r = Lx_k + beta_k (Lx_k - Lx_{k-1}) - c`` just ahead of the adjoint that reads it. Per
content row ``y`` (compiled: :func:`.stencil_kernels.sweep_rows`):

1. assemble ``r`` up to row ``y + R`` (the adjoint's reach); partial ``||r||^2``, ``<r, c>``;
2. ``g = L^T r`` on row ``y``;
3. ``y = x_k + beta (x_k - x_{k-1})``, ``x_{k+1} = clip(y - g / Lip)`` stored over ``x_{k-1}``;
   partial ``sum min(0, g)``, ``||y - x_{k+1}||^2``, ``<y - x_{k+1}, x_{k+1} - x_k>``;
4. add the row's light ``L[:, y] x_{k+1}[y]`` into ``Lx_{k+1}`` (stored over ``Lx_{k-1}``, whose
   rows step 1 has used by then); rows above ``y - R`` are final: partial ``||Lx_{k+1} - c||^2``.

The iterates are those of ``_apg`` (same step, restart rule, stopping rules and dual bound);
only the order of floating-point sums differs. Threads sweep contiguous row ranges; the rows
within ``R`` of a boundary are assembled before the threads start and finished after they end,
and each thread adds the light it throws across a boundary into a halo of its own, summed in
after. Channel-major arrays: ``(C, n)`` float32, viewed as ``(C, H, W)`` images.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Executor
from typing import Any

import cv2
import numpy as np

from imaging.compensation.stencil import StencilTransport
from imaging.compensation.workers import run_all

__all__ = ["fused_apg", "warm_up"]


class _Sweep:
    """The arrays of one solve and the steps of a band."""

    def __init__(self, st: StencilTransport, c: np.ndarray, x: np.ndarray, lip: float) -> None:
        self.st = st
        h, w = st.grid
        self.h, self.w, self.r = h, w, st.radius
        ch = c.shape[0]
        shape3 = (ch, h, w)
        self.c = c.reshape(shape3)
        self.x_cur = x.reshape(shape3)  # the solver's own copy: updated in place
        self.x_prev = np.empty(shape3, dtype=np.float32)  # x_{k-1}: read only once beta > 0 (not at k = 0)
        self.lx_cur = np.empty(shape3, dtype=np.float32)
        self.lx_prev = np.empty(shape3, dtype=np.float32)  # Lx_{k-1}: read only once beta > 0, like x_{k-1}
        self.res = np.empty(shape3, dtype=np.float32)  # r at y_k, assembled row by row
        self.step = np.float32(1.0 / lip)
        self.beta = np.float32(0.0)

    def assemble(self, y0: int, y1: int) -> tuple[float, float]:
        """``r = Lx_k + beta (Lx_k - Lx_{k-1}) - c`` on rows ``[y0, y1)``; returns ``(||r||^2, <r, c>)``."""
        if y1 <= y0:
            return 0.0, 0.0
        rr, rc = [], []
        b = float(self.beta)
        for ch in range(self.c.shape[0]):  # per channel: (rows, W) C-contiguous views OpenCV writes into
            rb, lc, cb = self.res[ch, y0:y1], self.lx_cur[ch, y0:y1], self.c[ch, y0:y1]
            if b != 0:
                cv2.addWeighted(lc, 1 + b, self.lx_prev[ch, y0:y1], -b, 0.0, dst=rb)  # one pass
                cv2.subtract(rb, cb, dst=rb)
            else:
                cv2.subtract(lc, cb, dst=rb)
            rr.append(cv2.norm(rb, cv2.NORM_L2SQR))  # float64 accumulation, no temporary
            rc.append(float(np.dot(rb.reshape(-1), cb.reshape(-1))))
        return math.fsum(rr), math.fsum(rc)

    def finish(self, y0: int, y1: int) -> float:
        """``||Lx_{k+1} - c||^2`` on camera rows ``[y0, y1)`` (``Lx_{k+1}`` lives in ``lx_prev`` during the sweep)."""
        if y1 <= y0:
            return 0.0
        return math.fsum(cv2.norm(self.lx_prev[ch, y0:y1], self.c[ch, y0:y1], cv2.NORM_L2SQR)
                         for ch in range(self.c.shape[0]))

    def sweep(self, y0: int, y1: int) -> tuple[list[float], list[tuple[int, np.ndarray]]]:
        """One thread's rows ``[y0, y1)``: partial sums (gneg, ymx, inner, f, rr, rc) and the light
        its content rows threw onto the ``R`` camera rows beyond each end, ``(first row, (C, R', W))``."""
        from imaging.compensation.stencil_kernels import sweep_rows  # Numba: loaded on the first sweep

        st, h, w, r = self.st, self.h, self.w, self.r
        first, last = y0 == 0, y1 == h
        lo = y0 if first else y0 + r  # rows within r of a boundary are assembled and finished outside
        hi = y1 if last else y1 - r
        ch = self.c.shape[0]
        top = np.zeros((ch, 0 if first else r, w), dtype=np.float32)
        bottom = np.zeros((ch, 0 if last else min(r, h - y1), w), dtype=np.float32)
        sums = sweep_rows(st.weights, np.float32(st.scale), r, self.c, self.x_cur, self.x_prev, self.lx_cur,
                          self.lx_prev, self.res, self.step, self.beta, y0, y1, lo, hi, top, bottom,
                          np.empty((ch, w), dtype=np.float32), np.empty((ch, w), dtype=np.float32))
        halos = ([] if first else [(y0 - r, top)]) + ([] if last else [(y1, bottom)])
        return list(sums), halos


def fused_apg(st: StencilTransport, c: np.ndarray, x: np.ndarray, *, lip: float, stop: Any, threads: int,
              pool: Executor | None, progress: Callable[[int, float], None] | None,
              dual_bound: Callable[[float, float, float], float]) -> tuple[np.ndarray, float, int, str]:
    """FISTA with gradient restart, one weight sweep per iteration (see the module docstring).

    ``c``: (C, n) float32 target, ``x``: (C, n) float32 start in [0, 1] (used as a work array: its
    values are overwritten); ``stop``: the solver's
    stopping rules (``history``, ``bound``, ``check``). Returns ``(x, f, iterations, reason)``
    with ``x`` (C, n) the last iterate and ``f`` its objective.
    """
    if st.tail is not None:
        raise ValueError("the fused sweep handles L without a stacked diagonal")
    s = _Sweep(st, c, x, lip)
    h, r = s.h, s.r
    ranges = st.bands(threads)
    if any(b - a <= 2 * r for a, b in ranges):
        ranges = [(0, h)]  # too few rows to share: one sweep
    run_all(pool, lambda rg: st.forward_rows(s.x_cur, s.lx_cur[:, rg[0] : rg[1]], rg[0], rg[1]), ranges)
    # no Lx_{-1} and x_{-1}: the first iteration has beta = 0 and reads neither
    f = math.fsum(cv2.norm(s.lx_cur[ch], s.c[ch], cv2.NORM_L2SQR) for ch in range(s.c.shape[0]))
    stop.history.append(f)
    if stop.max_iter == 0 or f <= 0:
        return s.x_cur.reshape(c.shape), f, 0, "optimal" if f <= 0 else "max_iter"
    t = 1.0
    k = 0
    while True:
        k += 1
        pre = [s.assemble(b0 - r, b0 + r) for _, b0 in ranges[:-1]]
        parts = run_all(pool, lambda rg: s.sweep(*rg), ranges)
        for _, halos in parts:
            for a, v in halos:
                s.lx_prev[:, a : a + v.shape[1]] += v
        f_late = [s.finish(b0 - r, b0 + r) for _, b0 in ranges[:-1]]
        gneg, ymx, inner, f, rr, rc = (math.fsum(p[0][j] for p in parts) for j in range(6))
        f = math.fsum([f, *f_late])
        rr = math.fsum([rr, *(p[0] for p in pre)])
        rc = math.fsum([rc, *(p[1] for p in pre)])
        stop.bound(dual_bound(rr, rc, gneg))
        if inner > 0:  # the momentum points uphill: restart
            t, beta = 1.0, 0.0
        else:
            t_next = 0.5 * (1 + math.sqrt(1 + 4 * t * t))
            beta = (t - 1) / t_next
            t = t_next
        s.beta = np.float32(beta)
        s.x_cur, s.x_prev = s.x_prev, s.x_cur
        s.lx_cur, s.lx_prev = s.lx_prev, s.lx_cur
        stop.history.append(f)
        if progress is not None:
            progress(k, f)
        why = stop.check(k, f, math.sqrt(ymx) * lip)
        if why is not None:
            return np.ascontiguousarray(s.x_cur.reshape(c.shape)), f, k, why


_WARM: set[str] = set()


class _Steps:
    """Stopping rules of a fixed number of iterations (``fused_apg``'s ``stop``)."""

    def __init__(self, max_iter: int) -> None:
        self.max_iter, self.history = max_iter, []

    def bound(self, value: float) -> None:
        pass

    def check(self, k: int, f: float, pg: float) -> str | None:
        return "max_iter" if k >= self.max_iter else None


def warm_up(storage: str) -> None:
    """Compile the kernels for ``storage`` (``"float32"`` or ``"uint16"``) on a tiny problem, or load
    them from Numba's cache, once per process: the first real solve must not spend its time budget or
    a video frame's deadline on the compiler. The tiny problem passes the same array types as a solve
    (the products on row views, the sweep on whole images, split over two row ranges)."""
    if storage in _WARM:
        return
    h, w, r = 12, 8, 1
    weights = np.ones((9, h, w), dtype=np.uint16 if storage == "uint16" else np.float32)
    st = StencilTransport((h, w), r, weights, scale=1.0 / 64 if storage == "uint16" else 1.0 / 9)
    for channels in (1, 2):  # a row range of one channel is contiguous, of several a strided view
        img = np.full((channels, h, w), 0.5, dtype=np.float32)
        out = np.empty((channels, h, w), dtype=np.float32)
        st.forward_rows(img, out[:, : h // 2], 0, h // 2)
        st.adjoint_rows(img, out[:, h // 2 :], h // 2, h)
    c = img[:1].reshape(1, -1)
    fused_apg(st, c, np.zeros_like(c), lip=2.0, stop=_Steps(2), threads=2, pool=None, progress=None,
              dual_bound=lambda rr, rc, gneg: 0.0)
    _WARM.add(storage)
