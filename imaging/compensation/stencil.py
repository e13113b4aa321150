"""Light transport as shifted weight images: ``L`` without index arrays.

When content and camera share one pixel grid (the camera's view rectified to the content, and
every synthetic rig of the benchmarks), column ``j`` of ``L`` holds content pixel ``j``'s PSF in
the ``(2R+1) x (2R+1)`` camera window centred on camera pixel ``j`` itself (the window structure
of :func:`~imaging.compensation.transport.transport_windows` with an identity mapping). Then

    ``L[j + dy * W + dx, j] = w_(dy,dx)[j]``

for ``K = (2R+1)^2`` weight images ``w_(dy,dx)`` of shape ``(H, W)``, and both products are sums
of shifted, weighted images::

    (L x)[y, x]   = sum_(dy,dx) w_(dy,dx)[y - dy, x - dx] * x[y - dy, x - dx]
    (L^T r)[y, x] = sum_(dy,dx) w_(dy,dx)[y, x]           * r[y + dy, x + dx]

Both read the *same* ``K`` images: no index arrays, no transposed copy. CSR moves 8 bytes per
non-zero per product (value and column index) and keeps ``L`` and ``L^T``; this storage moves 4
(``float32``) or 2 (``uint16`` fixed point: ``w = scale * q``, one scale for the matrix, absolute
error at most ``scale / 2``) and keeps one copy. A weight image is zero where its window entry
falls outside the camera (the edges), so no product ever wraps across a row.

Both products are compiled loops (:mod:`.stencil_kernels`) that go row by row: each weight row is
read once, converted from ``uint16`` in registers, and every offset of it is applied while the
few output rows it touches stay in the core's cache. They release the GIL; bands are split over
threads by whole rows, so threads never write the same pixel.

The ridge problem of :mod:`.ridge` stacks ``[L; sqrt(lam) I]``; a stacked diagonal below the
stencil is recognised too and applied as a pointwise product.
"""
from __future__ import annotations

import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["STORAGES", "StencilBand", "StencilTransport", "stencil_blocks", "stencil_from_csr"]

#: weight storages: exact float32, or uint16 fixed point (half the bytes)
STORAGES = ("float32", "uint16")
_MAX_RADIUS = 4  # K = 81: beyond this CSR is as compact and the band loop gets long


@dataclass
class StencilTransport:
    """``L`` (and an optional stacked diagonal) on one ``(H, W)`` pixel grid.

    Attributes
    ----------
    grid : (H, W)
        The shared content and camera grid; ``n = H * W``.
    radius : int
        ``R``; offsets ``(dy, dx)`` in ``[-R, R]^2``, row-major (``offsets[k]``).
    weights : (K, H, W) float32 or uint16
        ``w_(dy,dx)`` at the content pixel (the window's centre).
    scale : float
        Value of one ``uint16`` step (1.0 for float32 weights).
    tail : (n,) float32 or None
        Diagonal stacked below ``L``: the operator is ``[L; diag(tail)]``, shape ``(2n, n)``.
    """

    grid: tuple[int, int]
    radius: int
    weights: np.ndarray
    scale: float = 1.0
    tail: np.ndarray | None = None

    def __post_init__(self) -> None:
        r = self.radius
        self.offsets = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]
        h, w = self.grid
        if self.weights.shape != (len(self.offsets), h, w):
            raise ValueError(f"weights {self.weights.shape} do not fit grid {self.grid} at radius {r}")
        n = h * w
        self.shape = (2 * n if self.tail is not None else n, n)

    @property
    def storage(self) -> str:
        return "uint16" if self.weights.dtype == np.uint16 else "float32"

    @property
    def nbytes(self) -> int:
        """Bytes held (weights and the stacked diagonal)."""
        return int(self.weights.nbytes + (0 if self.tail is None else self.tail.nbytes))

    def bands(self, count: int) -> list[tuple[int, int]]:
        """``count`` row ranges ``(y0, y1)`` of about equal height covering the grid."""
        h = self.grid[0]
        cuts = np.linspace(0, h, max(1, min(count, h)) + 1).round().astype(int)
        return [(int(a), int(b)) for a, b in itertools.pairwise(cuts) if b > a]

    def forward_rows(self, x: np.ndarray, out: np.ndarray, y0: int, y1: int) -> None:
        """``out[c] = (L x[c])`` on camera rows ``[y0, y1)``.

        ``x``: (C, H, W) float32 content images; ``out``: (C, y1 - y0, W) float32, overwritten.
        """
        a, b = max(0, y0 - self.radius), min(self.grid[0], y1 + self.radius)  # the rows whose light lands there
        out.fill(0)
        self.scatter_band(x[:, a:b], a, b, [(y0, y1, out)])

    def adjoint_rows(self, v: np.ndarray, out: np.ndarray, y0: int, y1: int) -> None:
        """``out[c] = (L^T v[c])`` on content rows ``[y0, y1)``, from their weight rows only.

        ``v``: (C, H, W) float32 camera images; ``out``: (C, y1 - y0, W) float32, overwritten.
        """
        from imaging.compensation.stencil_kernels import adjoint_rows  # Numba: loaded on the first product

        adjoint_rows(self.weights, np.float32(self.scale), v, out, y0, y1, self.radius)

    def scatter_band(self, x: np.ndarray, y0: int, y1: int, sinks: list[tuple[int, int, np.ndarray]]) -> None:
        """Add the light of content rows ``[y0, y1)`` to the camera: ``L[:, band] x[band]``.

        ``x``: (C, y1 - y0, W) float32 content rows; ``sinks``: ``(r0, r1, view)`` with ``view``
        (C, r1 - r0, W) float32 accumulating camera rows ``[r0, r1)``; light landing on rows no
        sink holds is dropped (the caller's sinks must cover rows ``[y0 - R, y1 + R)`` inside the
        image).
        """
        from imaging.compensation.stencil_kernels import scatter_rows  # Numba: loaded on the first product

        scale = np.float32(self.scale)
        for r0, r1, view in sinks:
            scatter_rows(self.weights, scale, x, y0, y1, self.radius, view, r0, r1)

    def to_csr(self) -> sp.csr_matrix:
        """The matrix this storage represents (for tests and comparisons), CSR float32."""
        h, w = self.grid
        n = h * w
        j = np.arange(n, dtype=np.int64).reshape(h, w)
        rows, cols, vals = [], [], []
        for k, (dy, dx) in enumerate(self.offsets):
            ys, xs = slice(max(0, -dy), min(h, h - dy)), slice(max(0, -dx), min(w, w - dx))
            jj = j[ys, xs].ravel()
            vv = self.weights[k, ys, xs].ravel().astype(np.float32) * np.float32(self.scale)
            keep = vv != 0
            rows.append(jj[keep] + dy * w + dx)
            cols.append(jj[keep])
            vals.append(vv[keep])
        if self.tail is not None:
            rows.append(n + np.arange(n))
            cols.append(np.arange(n))
            vals.append(self.tail)
        m = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=self.shape)
        return m.tocsr()


def _images(v: np.ndarray, rows: int, width: int) -> np.ndarray:
    """A (C, rows * width) float32 array (rows contiguous) viewed as (C, rows, width) images, never copied."""
    out = v.view()
    out.shape = (v.shape[0], rows, width)  # raises instead of copying
    return out


class StencilBand:
    """One thread's share of a product: rows ``[y0, y1)`` of ``L x`` or of ``L^T v``.

    The operator's row blocks hold these where a CSR block would be; ``apply(v, out)`` takes
    the full ``(C, n_in)`` channel-major input and writes the block's ``(C, rows)`` output
    (``band @ v`` does the same for one channel).
    """

    def __init__(self, st: StencilTransport, y0: int, y1: int, adjoint: bool) -> None:
        self.st, self.y0, self.y1, self.adjoint = st, y0, y1, adjoint

    def apply(self, v: np.ndarray, out: np.ndarray) -> None:
        st = self.st
        h, w = st.grid
        n = h * w
        imgs = _images(v[:, :n], h, w)
        dst = _images(out, self.y1 - self.y0, w)
        if self.adjoint:
            st.adjoint_rows(imgs, dst, self.y0, self.y1)
            if st.tail is not None:  # + diag(tail) @ v[n:]
                a, b = self.y0 * w, self.y1 * w
                out += st.tail[a:b] * v[:, n + a : n + b]
        else:
            st.forward_rows(imgs, dst, self.y0, self.y1)

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        out = np.empty((1, (self.y1 - self.y0) * self.st.grid[1]), dtype=np.float32)
        self.apply(np.ascontiguousarray(v, dtype=np.float32)[None, :], out)
        return out[0]


class DiagonalBand:
    """The stacked diagonal's rows of ``[L; diag(d)] x``: ``d * x`` (a block of the forward product)."""

    def __init__(self, d: np.ndarray) -> None:
        self.d = d

    def apply(self, v: np.ndarray, out: np.ndarray) -> None:
        np.multiply(v, self.d, out=out)

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        return np.asarray(v, dtype=np.float32) * self.d


def stencil_blocks(st: StencilTransport, count: int) -> tuple[list, list]:
    """Forward and adjoint row blocks ``(start, stop, band)`` (flat indices) for ``count`` threads."""
    w = st.grid[1]
    n = st.grid[0] * w
    fwd = [(a * w, b * w, StencilBand(st, a, b, False)) for a, b in st.bands(count)]
    adj = [(a * w, b * w, StencilBand(st, a, b, True)) for a, b in st.bands(count)]
    if st.tail is not None:
        fwd.append((n, 2 * n, DiagonalBand(st.tail)))
    return fwd, adj


def _diagonal_tail(L: sp.csr_matrix) -> np.ndarray | None:
    """The diagonal ``d`` when ``L``'s last ``n`` rows are ``diag(d)`` below ``n`` others, else None."""
    m, n = L.shape
    if m != 2 * n:
        return None
    ptr = L.indptr[n:]
    if not np.all(np.diff(ptr) == 1) or not np.array_equal(L.indices[ptr[0] : ptr[-1]], np.arange(n)):
        return None
    return np.ascontiguousarray(L.data[ptr[0] : ptr[-1]], dtype=np.float32)


def _grid_width(L: sp.csr_matrix) -> tuple[int, int] | None:
    """Guess the grid width ``W`` and radius ``R`` from a row holding a full window, or None.

    A full window's column offsets ``i - j``, sorted, start with the ``2R+1`` entries of its
    ``dy = -R`` row; the next one is ``W`` further than the first. The guess is only a guess:
    :func:`stencil_from_csr` checks every entry against it.
    """
    counts = np.diff(L.indptr)
    if counts.size == 0:
        return None
    k = int(np.bincount(counts).argmax())
    r = (math.isqrt(k) - 1) // 2
    if k < 9 or (2 * r + 1) ** 2 != k or r > _MAX_RADIUS:
        return None
    full = np.flatnonzero(counts == k)
    i = int(full[full.size // 2])
    u = np.sort(i - L.indices[L.indptr[i] : L.indptr[i + 1]].astype(np.int64))
    w = int(u[2 * r + 1] - u[0])
    if w <= 2 * r or L.shape[1] % w:
        return None
    return w, r


def stencil_from_csr(L: sp.spmatrix, *, storage: str = "float32", threads: int = 2) -> StencilTransport | None:
    """``L`` as :class:`StencilTransport` when it has the shared-grid window structure, else None.

    ``L``: (n, n) or, with a stacked diagonal, (2n, n), in any CSR order (duplicates are summed;
    in ``uint16``, their rounded steps). Every entry is checked: it must lie within ``R`` rows and
    columns of its column's own pixel (so no window wraps across a row). The grid's height and
    width are inferred (``n = H * W``). ``storage``: ``"float32"`` (exact) or ``"uint16"``
    (non-negative ``L`` only, each entry rounded to the nearest of 65536 steps of ``max(L) /
    65535``; returns None otherwise). The copy is a compiled pass over ``L``'s CSR arrays
    (:func:`.stencil_kernels.extract_rows`), split over ``threads`` row ranges.
    """
    if storage not in STORAGES:
        raise ValueError(f"storage must be one of {STORAGES}, got {storage!r}")
    L = sp.csr_matrix(L)
    m, n = L.shape
    tail = None
    if m != n:
        tail = _diagonal_tail(L)
        if tail is None:
            return None
        L = L[:n]
    if n < 9 or L.nnz == 0:
        return None
    guess = _grid_width(L)
    if guess is None:
        return None
    w, r = guess
    h = n // w
    side = 2 * r + 1
    scale, inv = 1.0, 1.0
    if storage == "uint16":
        top = float(L.data.max())
        scale = top / 65535.0 if top > 0 else 1.0
        inv = 1.0 / scale
    weights = np.zeros((side * side, h, w), dtype=np.uint16 if storage == "uint16" else np.float32)
    data = L.data if L.data.dtype in (np.float32, np.float64) else L.data.astype(np.float64)
    from imaging.compensation.stencil_kernels import extract_rows  # Numba: loaded on the first extraction

    def part(rows: tuple[int, int]) -> bool:
        return bool(extract_rows(L.indptr, L.indices, data, weights, rows[0], rows[1], r, storage == "uint16", inv))

    st = StencilTransport((h, w), r, weights, scale, tail)
    bands = st.bands(threads)
    if len(bands) == 1:
        fits = [part(bands[0])]
    else:
        with ThreadPoolExecutor(len(bands)) as pool:
            fits = list(pool.map(part, bands))
    return st if all(fits) else None
