"""Bounded least squares for blur compensation: ``p' = argmin ||L p - c'||^2, 0 <= p <= 1``.

Everything is in linear luminance. ``L`` is the ``(n_camera, n_content)`` CSR light transport
(:mod:`.transport`), ``c'`` the target as the camera should see it, ``p'`` the one image every
projector shows (the summed method) or, for the baseline, one image per projector.

Methods
-------
``"apg"`` (default)
    FISTA with gradient-based adaptive restart (O'Donoghue & Candes 2015), step ``1/Lip``,
    ``Lip >= ||L||_2^2`` from power iterations capped by ``||L||_1 ||L||_inf``. Two products.
``"steepest"``
    The paper's reference: projected steepest descent with exact line search along the
    projected negative gradient (two or three sparse products per iteration).
``"lbfgsb"``
    SciPy's L-BFGS-B on the same objective (float64), for comparison.

Storage and dtype: products are memory-bound. ``L``, iterates and residuals are float32; every
reduction (objective, dual bound, dot products) is accumulated in float64. When content and
camera share a grid, ``L`` is read as shifted weight images (:mod:`.stencil`, a quarter of CSR's
bytes per iteration with the one-sweep APG of :mod:`.stencil_apg`), else as CSR row blocks of
``L`` and ``L^T``. Work runs on ``threads`` row blocks (the kernels release the GIL).

Stopping rules (:mod:`.stopping`; ``SolveResult.reason`` says which one stopped the solve):
``"gap"`` (certified by a dual bound, ``gap_tol``), ``"objective"`` (relative decrease over 5
iterations, ``tol``), ``"extrapolated"`` (the remaining decrease extrapolated from the last 10
iterations, ``est_tol``), ``"gradient"`` (``pg_tol``), ``"optimal"``, ``"max_iter"``, ``"time_limit"``.
"""
from __future__ import annotations

import math
import os
import time
import weakref
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from imaging.compensation.motion import MotionWarp
from imaging.compensation.stencil import STORAGES, stencil_blocks, stencil_from_csr
from imaging.compensation.stencil_apg import fused_apg, warm_up
from imaging.compensation.stencil_start import deconvolved_start
from imaging.compensation.stopping import CONVERGED, Stopper, dual_bound
from imaging.compensation.workers import run_all, workers

__all__ = [
    "TransportOperator",
    "SolveResult",
    "PerProjectorResult",
    "solve", "solve_per_projector",
    "objective", "dot32",
    "operator_for",
    "FrameCompensator",
]

Progress = Callable[[int, float], None]
METHODS = ("apg", "steepest", "lbfgsb")
_CHUNK = 1 << 16  # float32 elements per partial dot product (float64 accumulation across chunks)


def dot32(a: np.ndarray, b: np.ndarray) -> float:
    """Dot product of two float32 arrays of the same shape, accumulated in float64 across chunks.

    2-D views whose rows are contiguous (channel-major slices) are summed row by row, no copy.
    The chunks are also small enough that OpenBLAS does each on the calling thread: one long
    ``np.dot`` wakes its thread pool, whose threads then spin and take the cores from the
    solver's own threads (a solve of 4 iterations at 960x540 ran 30 ms slower right after one).
    """
    if a.ndim == 2 and not (a.flags.c_contiguous and b.flags.c_contiguous):
        return math.fsum(dot32(a[i], b[i]) for i in range(a.shape[0]))
    a, b = a.reshape(-1), b.reshape(-1)
    n = a.size
    if n <= _CHUNK:
        return float(np.dot(a, b))
    return math.fsum(float(np.dot(a[i : i + _CHUNK], b[i : i + _CHUNK])) for i in range(0, n, _CHUNK))


def _row_blocks(m: sp.csr_matrix, count: int) -> list[tuple[int, int, sp.csr_matrix]]:
    """Split ``m`` into ``count`` row blocks of about equal nnz, sharing ``m``'s arrays."""
    n = m.shape[0]
    if count <= 1 or n < 2 * count:
        return [(0, n, m)]
    targets = np.linspace(0, m.nnz, count + 1)[1:-1]
    cuts = [0, *np.searchsorted(m.indptr, targets).tolist(), n]
    cuts = sorted(set(min(max(c, 0), n) for c in cuts))
    blocks = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        s, e = int(m.indptr[a]), int(m.indptr[b])
        blk = sp.csr_matrix(
            (m.data[s:e], m.indices[s:e], m.indptr[a : b + 1] - m.indptr[a]), shape=(b - a, m.shape[1]), copy=False
        )
        blocks.append((a, b, blk))
    return blocks


class TransportOperator:
    """``L`` prepared for repeated solves: row blocks of ``L`` and ``L^T`` and a cached step bound.

    Parameters
    ----------
    L : scipy.sparse matrix, (n_camera, n_content)
        Converted once to CSR float32 (no copy if it already is). Treat it as immutable.
    threads : int, optional
        Row blocks / worker threads for products and updates (default: up to 2, the CPU count).
    storage : {"auto", "csr", "float32", "uint16"}
        How the products read ``L``. ``"csr"``: CSR blocks of ``L`` plus a CSR copy of ``L^T`` (about
        2 x 8 bytes per non-zero). ``"float32"`` / ``"uint16"``: shifted weight images (:mod:`.stencil`;
        4 or 2 bytes per window entry, one copy serves both products; their compiled kernels are
        loaded here), for an ``L`` whose content and camera grids coincide (``ValueError`` otherwise).
        ``"auto"`` (default): ``"float32"`` when ``L`` has that structure, else ``"csr"``.
    """

    def __init__(self, L: sp.spmatrix, *, threads: int | None = None, storage: str = "auto") -> None:
        if not sp.issparse(L) or L.ndim != 2:
            raise ValueError("L must be a 2-D scipy.sparse matrix")
        if storage not in ("auto", "csr", *STORAGES):
            raise ValueError(f"storage must be auto, csr, {' or '.join(STORAGES)}; got {storage!r}")
        L = sp.csr_matrix(L, dtype=np.float32, copy=False)
        self.shape: tuple[int, int] = (int(L.shape[0]), int(L.shape[1]))
        self.threads = max(1, int(threads if threads is not None else min(2, os.cpu_count() or 1)))
        self.stencil = None if storage == "csr" else \
            stencil_from_csr(L, storage="float32" if storage == "auto" else storage, threads=self.threads)
        self.L = L = L if self.stencil is not None or L.has_sorted_indices else L.sorted_indices()  # CSR's own order
        if self.stencil is None and storage in STORAGES:
            raise ValueError(f"L has no shared-grid window structure: storage {storage!r} does not apply")
        self.storage = "csr" if self.stencil is None else self.stencil.storage
        if self.stencil is not None: warm_up(self.storage)  # compiled here, not in a solve's time budget
        self.fused = True  #: APG on the stencil storage in one weight sweep per iteration (:mod:`.stencil_apg`)
        self._LT: sp.csr_matrix | None = None
        self.forward_blocks, self.adjoint_blocks = stencil_blocks(self.stencil, self.threads) if self.stencil is not None else \
            (_row_blocks(L, self.threads), _row_blocks(self.LT, self.threads))
        self._lipschitz: float | None = None
        self.lipschitz_info: dict[str, float] = {}

    @property
    def LT(self) -> sp.csr_matrix:
        """``L^T`` as CSR (built on first use; the stencil storage never needs it)."""
        self._LT = self.L.T.tocsr() if self._LT is None else self._LT
        return self._LT

    @property
    def storage_bytes(self) -> int:
        """Bytes the products read ``L`` from: CSR ``L`` and ``L^T``, or the weight images."""
        L = self.L
        return self.stencil.nbytes if self.stencil is not None else 2 * int(L.data.nbytes + L.indices.nbytes + L.indptr.nbytes)

    def bytes_per_iteration(self, channels: int = 1) -> int:
        """What one APG iteration must move through memory, at least: ``L`` read once per product
        (CSR: ``L`` and ``L^T``; stencil: the weights twice, or once in the fused sweep) and the
        float32 vectors (``r``, ``x_k``, ``x_{k-1}``, ``c``, ``Lx_k`` read, ``x_{k+1}``, ``Lx_{k+1}``, ``r`` written)."""
        m, n = self.shape
        twice = self.stencil is not None and not (self.fused and self.stencil.tail is None)
        return self.storage_bytes * (2 if twice else 1) + 4 * channels * (5 * n + 6 * m)

    @property
    def nnz(self) -> int:
        return int(self.L.nnz)

    def clear_cache(self) -> None:
        """Forget the cached step bound (benchmarks time it as part of a solve)."""
        self._lipschitz, self.lipschitz_info = None, {}

    def matvec(self, x: np.ndarray, *, pool: Executor | None = None) -> np.ndarray:
        """``L @ x`` for ``x`` of shape (n_content,) or (n_content, C), float32."""
        return self._apply(self.forward_blocks, self.shape[0], x, pool)

    def rmatvec(self, r: np.ndarray, *, pool: Executor | None = None) -> np.ndarray:
        """``L^T @ r`` for ``r`` of shape (n_camera,) or (n_camera, C), float32."""
        return self._apply(self.adjoint_blocks, self.shape[1], r, pool)

    @staticmethod
    def _apply(blocks: list, rows: int, v: np.ndarray, pool: Executor | None) -> np.ndarray:
        v = np.asarray(v, dtype=np.float32)
        if v.ndim == 1:
            vt = np.ascontiguousarray(v)[None, :]
        elif v.ndim == 2:
            vt = np.ascontiguousarray(v.T)  # channel-major: one contiguous vector per channel
        else:
            raise ValueError(f"expected (n,) or (n, C), got {v.shape}")
        out = np.empty((vt.shape[0], rows), dtype=np.float32)

        def one(block: tuple[int, int, Any]) -> None:
            a, b, m = block
            _block_apply(m, vt, out[:, a:b])

        run_all(pool, one, blocks)
        return out[0] if v.ndim == 1 else np.ascontiguousarray(out.T)

    def lipschitz(self, *, iterations: int = 6, pool: Executor | None = None, early_exit: bool = True) -> float:
        """A step bound ``Lip >= ||L||_2^2`` (largest eigenvalue of ``L^T L``), cached.

        ``||L||_1 ||L||_inf`` (Schur) is a guaranteed bound, and tight for a blur whose top
        singular vector is nearly constant. A few power iterations from the all-ones vector
        give a lower estimate; when it is clearly below the Schur bound the step uses the
        estimate raised by 5 %. The estimates never decrease (Rayleigh quotients of a power
        iteration on ``L^T L``), so once 1.05 x the estimate reaches the Schur bound the result
        is the Schur bound and ``early_exit`` stops there. Products on ``pool``, else the operator's threads.
        """
        pool = workers(self.threads) if pool is None else pool
        if self._lipschitz is None:
            if negative := bool(self.L.nnz) and float(self.L.data.min()) < 0:
                absL = abs(self.L)
                col = np.asarray(absL.sum(axis=0)).ravel()
                row = np.asarray(absL.sum(axis=1)).ravel()
            else:
                row = self.matvec(np.ones(self.shape[1], dtype=np.float32), pool=pool)
                col = self.rmatvec(np.ones(self.shape[0], dtype=np.float32), pool=pool)
            schur = float(col.max(initial=0.0)) * float(row.max(initial=0.0))
            v = np.ones(self.shape[1], dtype=np.float32)
            est = 0.0
            for k in range(iterations):
                w = self.matvec(v, pool=pool) if k or negative else row  # L 1 is the Schur bound's row sums
                est = dot32(w, w) / max(dot32(v, v), 1e-300)
                if early_exit and 1.05 * est >= schur:
                    break
                v = self.rmatvec(w, pool=pool)
                nv = math.sqrt(dot32(v, v))
                if nv == 0:
                    break
                v /= np.float32(nv)
            lip = min(schur, 1.05 * est) if est > 0 else schur
            self._lipschitz = max(lip, 1e-12)
            self.lipschitz_info = {"power_estimate": est, "schur_bound": schur, "lipschitz": self._lipschitz}
        return self._lipschitz


def _block_apply(m: Any, v: np.ndarray, out: np.ndarray) -> None:
    """``out[c] = m @ v[c]`` for every channel: a CSR block one channel at a time, a stencil band all at once."""
    if hasattr(m, "apply"):
        m.apply(v, out)
    else:
        for k in range(v.shape[0]):
            out[k] = m @ v[k]


_OPERATORS: dict[int, tuple[Any, TransportOperator]] = {}


def operator_for(L: sp.spmatrix | TransportOperator, *, threads: int | None = None) -> TransportOperator:
    """The cached :class:`TransportOperator` of ``L`` (built on first use, dropped with ``L``)."""
    if isinstance(L, TransportOperator):
        return L
    key = id(L)
    hit = _OPERATORS.get(key)
    if hit is not None and hit[0]() is L and (threads is None or hit[1].threads == threads):
        return hit[1]
    op = TransportOperator(L, threads=threads)
    try:
        ref = weakref.ref(L, lambda _r, key=key: _OPERATORS.pop(key, None))
    except TypeError:
        return op
    _OPERATORS[key] = (ref, op)
    return op


@dataclass
class SolveResult:
    """Outcome of :func:`solve`.

    ``x`` has the content shape (``(H, W)`` / ``(H, W, C)`` when known, else ``(n,)`` /
    ``(n, C)``), float32 in [0, 1]. ``objective`` is ``||L x - c'||^2`` (float64 sum over
    channels). ``gap`` is the certified relative gap ``(objective - bound) / bound`` at the
    end (``inf`` when no positive bound is known). ``history`` holds the objective after
    every iteration.
    """

    x: np.ndarray
    objective: float
    iterations: int
    converged: bool
    reason: str
    history: list[float] = field(default_factory=list)
    gap: float = math.inf
    lower_bound: float = 0.0
    seconds: float = 0.0
    method: str = "apg"
    lipschitz: float = 0.0


@dataclass
class PerProjectorResult:
    """Outcome of :func:`solve_per_projector`: one image and one :class:`SolveResult` per projector."""

    xs: list[np.ndarray]
    results: list[SolveResult]
    seconds: float

    @property
    def iterations(self) -> int:
        return sum(r.iterations for r in self.results)


def objective(L: sp.spmatrix | TransportOperator, x: np.ndarray, target: np.ndarray) -> float:
    """``||L x - c||^2`` in float64; ``x`` and ``target`` as accepted by :func:`solve`."""
    op = operator_for(L)
    xv = np.asarray(x, dtype=np.float32).reshape(op.shape[1], -1)
    c = np.asarray(target, dtype=np.float32).reshape(op.shape[0], -1)
    if xv.shape[1] != c.shape[1]:
        raise ValueError(f"x has {xv.shape[1]} channels, target {c.shape[1]}")
    r = op.matvec(xv) - c
    return dot32(r, r)


def _prepare(
    op: TransportOperator, target: np.ndarray, x0: np.ndarray | None, content_shape: Sequence[int] | None
) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Flatten target/x0 into (n, C) float32 and work out the output shape."""
    m, n = op.shape
    c = np.asarray(target)
    if c.ndim == 1 or (c.ndim == 2 and c.shape[0] == m and c.size != m):
        spatial, channels = None, (c.shape[1:] if c.ndim == 2 else ())
        if c.shape[0] != m:
            raise ValueError(f"target has {c.shape[0]} pixels, L has {m} camera pixels")
    elif c.ndim in (2, 3):
        spatial, channels = c.shape[:2], c.shape[2:]
        if spatial[0] * spatial[1] != m:
            raise ValueError(f"target image {c.shape} has {spatial[0] * spatial[1]} pixels, L has {m} camera pixels")
    else:
        raise ValueError(f"target must be (n,), (n, C), (H, W) or (H, W, C), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("target contains NaN or infinity")
    nc = int(channels[0]) if channels else 1
    if content_shape is not None:
        cs = tuple(int(v) for v in content_shape)
        if len(cs) != 2 or cs[0] * cs[1] != n:
            raise ValueError(f"content_shape {cs} does not hold L's {n} content pixels")
        out_shape: tuple[int, ...] = (*cs, *channels)
    elif spatial is not None and n == m:
        out_shape = (*spatial, *channels)
    else:
        out_shape = (n, *channels)
    c2 = np.ascontiguousarray(c, dtype=np.float32).reshape(m, nc)
    if x0 is None and n == m:  # the target, deconvolved by the stencil's mean blur when L is one (a far better start)
        x = deconvolved_start(op.stencil, c2, workers=op.threads) if op.stencil is not None else np.clip(c2, 0, 1)
    elif x0 is None:
        ones = op.matvec(np.ones(n, dtype=np.float32))
        scale = np.array([dot32(ones, c2[:, j].copy()) for j in range(nc)]) / max(dot32(ones, ones), 1e-30)
        x = np.array(np.broadcast_to(np.clip(scale, 0, 1).astype(np.float32), (n, nc)), order="C")
    else:
        x = np.array(x0, dtype=np.float32, order="C").reshape(-1)
        if x.size != n * nc:
            raise ValueError(f"x0 has {x.size} values, expected {n * nc} ({n} content pixels x {nc} channels)")
        x = x.reshape(n, nc)
        np.fmin(np.fmax(x, 0, out=x), 1, out=x)  # into [0, 1]; fmax takes NaN to 0, as nan_to_num then clip did
    return c2, x, out_shape


def solve(
    L: sp.spmatrix | TransportOperator,
    target: np.ndarray,
    *,
    x0: np.ndarray | None = None,
    method: str = "apg",
    tol: float = 1e-5,
    gap_tol: float = 1e-3,
    pg_tol: float = 1e-6,
    est_tol: float = 0.0,
    max_iter: int = 500,
    time_limit: float | None = None,
    content_shape: Sequence[int] | None = None,
    progress: Progress | None = None,
    threads: int | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> SolveResult:
    """Solve ``min ||L x - target||^2`` subject to ``0 <= x <= 1``.

    Parameters
    ----------
    L : scipy.sparse matrix (n_camera, n_content) or TransportOperator
        Light transport; a matrix gets a cached :class:`TransportOperator`.
    target : (n_camera,), (n_camera, C), (Hc, Wc) or (Hc, Wc, C) array
        Desired camera image in linear luminance; channels are solved together.
    x0 : array, optional
        Warm start (e.g. the previous frame's solution), any shape holding n_content x C
        values; clipped to [0, 1]. Default: the target itself when L is square (deconvolved by
        the mean stencil, :mod:`.stencil_start`, on the stencil storage), else the best uniform grey.
    method : {"apg", "steepest", "lbfgsb"}
    tol, gap_tol, pg_tol, est_tol, max_iter, time_limit :
        Stopping rules (:mod:`.stopping`); ``0`` disables a tolerance. ``est_tol`` (off by
        default) applies to ``"apg"`` and ``"steepest"``.
    content_shape : (H, W), optional
        Shape of the returned image (default: the target's when L is square).
    progress : callable(iteration, objective), optional
        Called after every iteration.
    threads : int, optional
        Worker threads (default: the operator's).
    clock : callable
        Monotonic clock in seconds (injectable for tests).

    Returns
    -------
    SolveResult
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if max_iter < 0:
        raise ValueError(f"max_iter must be >= 0, got {max_iter}")
    op = operator_for(L, threads=threads)
    start = clock()  # the cold start (two FFTs per channel on the stencil storage) is part of the solve's time
    c, x, out_shape = _prepare(op, target, x0, content_shape)
    pool = workers(op.threads if threads is None else max(1, threads))
    if method == "lbfgsb":
        res = _lbfgsb(op, c, x, tol=tol, pg_tol=pg_tol, max_iter=max_iter, time_limit=time_limit,
                      progress=progress, clock=clock, start=start, pool=pool)
    else:
        lip = op.lipschitz(pool=pool)
        fused = method == "apg" and op.stencil is not None and op.stencil.tail is None and op.fused
        runner = _fused if fused else _apg if method == "apg" else _steepest
        res = runner(op, c, x, lip=lip, tol=tol, gap_tol=gap_tol, pg_tol=pg_tol, est_tol=est_tol, max_iter=max_iter,
                     time_limit=time_limit, progress=progress, clock=clock, start=start, pool=pool)
        res.lipschitz = lip
    res.method = method
    res.seconds = clock() - start
    res.x = res.x.reshape(out_shape)
    return res


def _apg(op: TransportOperator, c: np.ndarray, x: np.ndarray, *, lip: float, tol: float, gap_tol: float,
         pg_tol: float, est_tol: float, max_iter: int, time_limit: float | None, progress: Progress | None,
         clock: Callable[[], float], start: float, pool: Executor | None) -> SolveResult:
    """FISTA with gradient-based adaptive restart; fused, row-blocked updates."""
    stop = Stopper(tol=tol, gap_tol=gap_tol, pg_tol=pg_tol, est_tol=est_tol, max_iter=max_iter, time_limit=time_limit,
                   clock=clock, start=start)
    fwd, adj = op.forward_blocks, op.adjoint_blocks
    step = np.float32(1.0 / lip)
    # channel-major (C, n) layout: every channel of every row block is one contiguous vector
    c = np.ascontiguousarray(c.T)
    x_cur = np.ascontiguousarray(x.T)  # x_k
    x_prev = x_cur.copy()  # x_{k-1} (equal at start: y_0 = x_0)
    lx_cur = np.ascontiguousarray(op.matvec(x).T)
    r = lx_cur - c  # residual at y
    f = dot32(r, r)
    stop.history.append(f)
    if max_iter == 0 or f <= 0:
        return SolveResult(x=np.ascontiguousarray(x_cur.T), objective=f, iterations=0, converged=f <= 0,
                           reason="optimal" if f <= 0 else "max_iter", history=stop.history)
    rr, rc = f, dot32(r, c)
    lx_new = np.empty_like(lx_cur)
    beta = 0.0
    t = 1.0
    k = 0
    reason = "max_iter"
    while True:
        k += 1
        b32 = np.float32(beta)

        parts = run_all(pool, _content_phase_factory(x_cur, x_prev, r, step, b32), adj)
        gneg = math.fsum(p[0] for p in parts)
        ymx = math.fsum(p[1] for p in parts)
        inner = math.fsum(p[2] for p in parts)
        # x_prev now holds x_{k+1}; swap names
        x_cur, x_prev = x_prev, x_cur
        stop.bound(dual_bound(rr, rc, gneg))
        if inner > 0:  # the momentum points uphill: restart
            t = 1.0
            beta_next = 0.0
        else:
            t_next = 0.5 * (1 + math.sqrt(1 + 4 * t * t))
            beta_next = (t - 1) / t_next
            t = t_next
        bn = np.float32(beta_next)

        def camera_phase(block: tuple[int, int, Any]) -> tuple[float, float, float]:
            a, b, m = block
            lxn = lx_new[:, a:b]
            _block_apply(m, x_cur, lxn)
            cb = c[:, a:b]
            rb = r[:, a:b]
            np.subtract(lxn, cb, out=rb)
            fpart = dot32(rb, rb)
            # y_{k+1} = x_{k+1} + beta (x_{k+1} - x_k)  =>  L y = Lx_{k+1} + beta (Lx_{k+1} - Lx_k)
            if beta_next != 0.0:
                lxc = lx_cur[:, a:b]
                np.subtract(lxn, lxc, out=lxc)
                lxc *= bn
                rb += lxc
            return fpart, dot32(rb, rb), dot32(rb, cb)

        cparts = run_all(pool, camera_phase, fwd)
        f = math.fsum(p[0] for p in cparts)
        rr = math.fsum(p[1] for p in cparts)
        rc = math.fsum(p[2] for p in cparts)
        lx_cur, lx_new = lx_new, lx_cur
        beta = beta_next
        stop.history.append(f)
        if progress is not None:
            progress(k, f)
        why = stop.check(k, f, math.sqrt(ymx) * lip)
        if why is not None:
            reason = why
            break
    # x_cur holds the last iterate and f its objective (the extrapolated point y is discarded)
    return SolveResult(x=np.ascontiguousarray(x_cur.T), objective=f, iterations=k, converged=reason in CONVERGED,
                       reason=reason, history=stop.history, gap=stop.gap(f), lower_bound=max(stop.lower, 0.0))


def _fused(op: TransportOperator, c: np.ndarray, x: np.ndarray, *, lip: float, progress: Progress | None,
           pool: Executor | None, **rules: Any) -> SolveResult:
    """:func:`_apg`'s iterates in one sweep over the stencil weights per iteration (``rules``: :class:`.stopping.Stopper`'s)."""
    stop = Stopper(**rules)
    xs, f, k, reason = fused_apg(op.stencil, np.ascontiguousarray(c.T), np.ascontiguousarray(x.T), lip=lip, stop=stop,
                                 threads=op.threads if pool is not None else 1, pool=pool, progress=progress,
                                 dual_bound=dual_bound)
    return SolveResult(x=np.ascontiguousarray(xs.T), objective=f, iterations=k, reason=reason, history=stop.history,
                       converged=reason in CONVERGED, gap=stop.gap(f), lower_bound=max(stop.lower, 0.0))


def _content_phase_factory(x_cur: np.ndarray, x_prev: np.ndarray, r: np.ndarray, step: np.float32, beta: np.float32):
    """One content-row block of an APG iteration (arrays channel-major: (C, n)).

    Computes ``g = (L^T r)[a:b]`` (gradient at ``y``), ``y = x_k + beta (x_k - x_{k-1})`` and
    ``x_{k+1} = clip(y - g / Lip)``, stores ``x_{k+1}`` over ``x_{k-1}`` and returns the partial
    sums ``(sum min(0, g), ||y - x_{k+1}||^2, <y - x_{k+1}, x_{k+1} - x_k>)``.
    """

    def phase(block: tuple[int, int, Any]) -> tuple[float, float, float]:
        a, b, m = block
        xc, xp = x_cur[:, a:b], x_prev[:, a:b]  # (C, nb) views
        g = np.empty(xc.shape, dtype=np.float32)
        _block_apply(m, r, g)
        gneg = float(np.minimum(g, 0).sum(dtype=np.float64))
        if beta != 0:
            y = np.subtract(xc, xp)  # beta (x_k - x_{k-1}) + x_k
            y *= beta
            y += xc
        else:
            y = xc.copy()
        g *= -step
        g += y
        np.clip(g, 0, 1, out=g)  # x_{k+1}
        y -= g  # y - x_{k+1}
        ymx = dot32(y, y)
        np.subtract(g, xc, out=xp)  # x_{k+1} - x_k (scratch in x_{k-1}'s slot)
        inner = dot32(y, xp)
        xp[...] = g  # store x_{k+1}
        return gneg, ymx, inner

    return phase


def _steepest(op: TransportOperator, c: np.ndarray, x: np.ndarray, *, lip: float, tol: float, gap_tol: float,
              pg_tol: float, est_tol: float, max_iter: int, time_limit: float | None, progress: Progress | None,
              clock: Callable[[], float], start: float, pool: Executor | None) -> SolveResult:
    """Projected steepest descent with exact line search (the paper's reference method)."""
    stop = Stopper(tol=tol, gap_tol=gap_tol, pg_tol=pg_tol, est_tol=est_tol, max_iter=max_iter, time_limit=time_limit,
                   clock=clock, start=start)
    lx = op.matvec(x, pool=pool)
    r = lx - c
    f = dot32(r, r)
    stop.history.append(f)
    k = 0
    reason = "max_iter" if max_iter == 0 else "optimal"
    while max_iter > 0 and f > 0:
        k += 1
        g = op.rmatvec(r, pool=pool)
        stop.bound(dual_bound(f, dot32(r, c), float(np.minimum(g, 0).sum(dtype=np.float64))))
        d = np.negative(g)
        d[((x <= 0) & (g > 0)) | ((x >= 1) & (g < 0))] = 0
        dd = dot32(d, d)
        if dd == 0:
            reason = "optimal"
            break
        ld = op.matvec(d, pool=pool)
        ldld = dot32(ld, ld)
        if ldld <= 0:
            reason = "optimal"
            break
        alpha = np.float32(dd / ldld)
        x_new = x + alpha * d
        clipped = bool(np.any(x_new < 0) or np.any(x_new > 1))
        if clipped:
            np.clip(x_new, 0, 1, out=x_new)
            lx = op.matvec(x_new, pool=pool)
        else:
            lx += alpha * ld
        x = x_new
        np.subtract(lx, c, out=r)
        f = dot32(r, r)
        stop.history.append(f)
        if progress is not None:
            progress(k, f)
        why = stop.check(k, f, math.sqrt(dd))
        if why is not None:
            reason = why
            break
    return SolveResult(x=x, objective=f, iterations=k, converged=reason in CONVERGED,
                       reason=reason, history=stop.history, gap=stop.gap(f), lower_bound=max(stop.lower, 0.0))


def _lbfgsb(op: TransportOperator, c: np.ndarray, x: np.ndarray, *, tol: float, pg_tol: float, max_iter: int,
            time_limit: float | None, progress: Progress | None, clock: Callable[[], float], start: float,
            pool: Executor | None) -> SolveResult:
    """SciPy's L-BFGS-B on ``||Lx - c||^2`` (float64 iterates, float32 products)."""
    from scipy.optimize import minimize  # lazy: scipy.optimize is slow to import and only this method needs it

    shape = x.shape
    history: list[float] = []
    state: dict[str, Any] = {"k": 0, "reason": None}
    r0 = op.matvec(x, pool=pool) - c
    f0 = dot32(r0, r0)
    history.append(f0)
    if max_iter == 0 or f0 <= 0:
        return SolveResult(x=x, objective=f0, iterations=0, converged=f0 <= 0,
                           reason="optimal" if f0 <= 0 else "max_iter", history=history)
    scale = 1.0 / f0  # L-BFGS-B's ftol is absolute below 1: work on f / f0

    def fun(v: np.ndarray) -> tuple[float, np.ndarray]:
        xv = v.astype(np.float32).reshape(shape)
        r = op.matvec(xv, pool=pool) - c
        g = op.rmatvec(r, pool=pool)
        return dot32(r, r) * scale, (2.0 * scale) * g.astype(np.float64).reshape(-1)

    def callback(intermediate_result: Any) -> None:
        state["k"] += 1
        fk = float(intermediate_result.fun) / scale
        history.append(fk)
        if progress is not None:
            progress(state["k"], fk)
        if time_limit is not None and clock() - start >= time_limit:
            state["reason"] = "time_limit"
            raise StopIteration

    # projected gradient (infinity norm) at the start, for the relative pg_tol
    g0 = 2.0 * scale * op.rmatvec(r0, pool=pool).astype(np.float64)
    pg0 = float(np.abs(np.clip(x - g0, 0, 1) - x).max())
    res = minimize(fun, x.reshape(-1).astype(np.float64), jac=True, method="L-BFGS-B", bounds=[(0.0, 1.0)] * x.size,
                   callback=callback, options={"maxiter": max_iter, "ftol": max(tol, 1e-15),
                                               "gtol": max(pg_tol * pg0, 1e-300), "maxcor": 10})
    xs = np.clip(res.x, 0, 1).astype(np.float32).reshape(shape)
    f = objective(op, xs, c)
    if state["reason"]:
        reason = state["reason"]
    elif res.nit >= max_iter:
        reason = "max_iter"
    elif res.success:
        reason = "gradient" if "PROJ_GRAD" in str(res.message) else "objective"
    else:
        reason = "stalled"
    return SolveResult(x=xs, objective=f, iterations=int(res.nit), converged=bool(res.success) and not state["reason"],
                       reason=reason, history=history)


def solve_per_projector(
    L_list: Sequence[sp.spmatrix | TransportOperator],
    target: np.ndarray,
    **options: Any,
) -> PerProjectorResult:
    """The conventional baseline: ``p_i = argmin ||L_i p_i - target / N||^2``, ``0 <= p_i <= 1``, for each i.

    ``options`` are those of :func:`solve` (``x0``, if given, is a sequence of N warm starts).
    The N bounded solves run one after the other; the time grows linearly with N.
    """
    if not L_list:
        raise ValueError("no projectors")
    n = len(L_list)
    share = np.asarray(target, dtype=np.float32) / np.float32(n)
    x0s = options.pop("x0", None)
    if x0s is not None and len(x0s) != n:
        raise ValueError(f"{n} projectors but {len(x0s)} warm starts")
    clock = options.get("clock", time.perf_counter)
    start = clock()
    results = [solve(Li, share, x0=None if x0s is None else x0s[i], **options) for i, Li in enumerate(L_list)]
    return PerProjectorResult(xs=[r.x for r in results], results=results, seconds=clock() - start)


class FrameCompensator:
    """Warm-started compensation of a video, one bounded solve per frame.

    Each frame starts from the previous frame's solution; when content and camera grids
    coincide (square ``L``) the start also adds the change of the target since the previous
    frame (``delta``), which follows moving content far better than the bare previous
    solution. Every frame then runs at most ``iterations`` APG iterations (``first_iterations``
    for the first frame or after :meth:`reset`), so the time per frame is bounded.

    Parameters
    ----------
    L : scipy.sparse matrix or TransportOperator
    iterations, first_iterations : int
        Iteration budget per frame and for a cold start.
    delta : bool
        Add the target change to the warm start (square ``L`` only). On the stencil storage the
        change of the *deconvolved* target (:mod:`.stencil_start`, its kernel cut at twice the
        PSF's radius): its sharpening is nearly exact for the new picture, the carried correction
        ``x - deconvolved(c)`` small and smooth.
    motion : bool
        With ``delta`` and image-shaped targets: move the previous correction (``x - c``, or
        ``x - deconvolved(c)``) along the target's motion first (:class:`.motion.MotionWarp`).
    deadline : float, optional
        Seconds per frame: a warm-started frame stops after the iteration that crosses it
        (its result then says ``reason == "time_limit"``).
    solve_options :
        Passed to :func:`solve` (``tol``, ``time_limit``, ``content_shape``, ``threads`` ...).
    """

    def __init__(self, L: sp.spmatrix | TransportOperator, *, iterations: int = 4, first_iterations: int = 60,
                 delta: bool = True, motion: bool = False, deadline: float | None = None, **solve_options: Any) -> None:
        if iterations < 1 or first_iterations < 1:
            raise ValueError("iteration budgets must be >= 1")
        if deadline is not None:
            if deadline <= 0:
                raise ValueError(f"deadline must be positive, got {deadline}")
            solve_options["time_limit"] = deadline
        self.op = operator_for(L, threads=solve_options.pop("threads", None))
        self.iterations = iterations
        self.first_iterations = first_iterations
        self.delta = delta and self.op.shape[0] == self.op.shape[1]
        self.motion = MotionWarp() if motion and self.delta else None
        self.options = {"gap_tol": 0.0, "pg_tol": 0.0, **solve_options}
        self._x = self._target = self._base = None  # the previous frame's solution, target and base

    def reset(self) -> None:
        """Forget the previous frame (e.g. after a cut)."""
        self._x = self._target = self._base = None

    def __call__(self, target: np.ndarray, *, progress: Progress | None = None) -> SolveResult:
        """Compensate one frame (same shapes as :func:`solve`); returns its :class:`SolveResult`."""
        target = np.asarray(target, dtype=np.float32)
        st = self.op.stencil if self.delta else None
        # the deconvolution by the kernel cut at twice the PSF's radius: as good a start as the FFTs'
        # once the carried correction absorbs the difference, at a fraction of their cost (.stencil_start)
        base = target if st is None else deconvolved_start(st, target.reshape(self.op.shape[1], -1),
                                                           radius=2 * st.radius).reshape(target.shape)
        x0, budget = (None if st is None else base), self.first_iterations  # base: the cold start
        if self._x is not None and self._target is not None and self._target.shape == target.shape:
            budget = self.iterations
            if self.delta:
                corr = self._x.reshape(target.shape) - self._base
                if self.motion is not None and target.ndim in (2, 3) and target.shape[-1] != 1:
                    corr = self.motion(corr, self._target, target).reshape(target.shape)
                x0 = base + corr
            else:
                x0 = self._x
        res = solve(self.op, target, x0=x0, max_iter=budget, progress=progress, **self.options)
        self._x, self._target, self._base = res.x, target, base
        return res
