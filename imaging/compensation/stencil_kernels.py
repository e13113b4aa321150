"""The stencil storage's compiled loops: both products and the APG sweep, a weight row at a time.

:mod:`.stencil` defines ``L`` by ``K = (2R+1)^2`` weight images ``w_(dy,dx)`` (row-major offsets,
``k = (dy + R) * (2R+1) + (dx + R)``) and ``scale`` (one ``uint16`` step, 1.0 for float32)::

    (L x)[y + dy, x + dx] += scale * w_(dy,dx)[y, x] * x[y, x]
    (L^T v)[y, x]          = scale * sum_(dy,dx) w_(dy,dx)[y, x] * v[y + dy, x + dx]

OpenCV needs one ``accumulateProduct`` per offset and channel over a whole band, and a ``uint16``
band must first be converted to float32 in a separate pass. Here, per weight row, Numba's loop
over the row's pixels reads the ``uint16`` (or float32) weights once, converts them in registers
and accumulates into output rows that stay in the core's first-level cache. The offsets of one
``dy`` are applied together, five per pass (:func:`gather_taps`, :func:`scatter_taps`): each
output pixel is loaded and stored once per five multiply-adds instead of once per offset, which
made both products about a quarter faster on one core at 2592x1944. Three channels (RGB) share
each pass (:func:`gather_taps3`, :func:`scatter_taps3`): a weight is loaded and converted once for
the three, which halved the three-channel products on one core. LLVM vectorises each pass (a
plain ``d[i] += w0[i] * s[i] + ...`` over unit-stride slices, indexed from 0 so no negative-index
check blocks it); the few columns near the row's ends where some offset falls outside go offset
by offset. The passes and the per-row helpers are functions of their own, not inlined: an
inlined copy at every call site made the first compile take minutes. The kernels release the
GIL, so the solver's threads run them on separate row ranges at once.

The sums are in float32, as OpenCV's were; only their order per output pixel may differ (and
with it the last bits). The tests compare both products against SciPy's CSR product of the same
matrix.

``sweep_rows`` is one thread's share of an iteration of :mod:`.stencil_apg`, one content row at a
time: each row is assembled, differentiated, updated (:func:`update_row`, written so that LLVM
vectorises it) and scattered before the next starts, so the weight row the adjoint read is still
in the first-level cache when the scatter reads it again and ``L`` streams from memory once per
iteration. It may reassociate its sums and fuse multiply-adds
(``fastmath`` reassoc and contract, nothing that assumes finite values), so its float64 reductions
vectorise too (about 10 % faster at 2592x1944); its iterates differ from a plain loop's only in
float32's last bits. All kernels live in this one module because Numba's cache follows a
function's own file only: an inlined helper changed in another file would leave stale machine code.

``extract_rows`` builds the weights from ``L``'s CSR arrays, checking every entry's place.

Shapes: ``w`` (K, H, W) uint16 or float32; images (C, rows, W) float32 with unit-stride rows.
The first call of each kernel for a new combination of argument types compiles it (all a solve
needs: about 25 s per weight type here, once after an install); the machine code is cached beside
this module for the next process.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["adjoint_row", "adjoint_rows", "extract_rows", "gather_group", "gather_taps", "scatter_group", "scatter_rows",
           "scatter_taps", "sweep_rows"]


_GROUP = 5  # offsets of one weight row applied in one pass over its output row


@njit(nogil=True, cache=True, fastmath={"contract"})
def gather_taps(d, w, k0, y, c0, s, n):  # pragma: no cover - compiled
    """``d[i] += sum_(t < n) w[k0 + t, y, c0 + i] * s[i + t]`` (``s``: ``len(d) + n - 1`` values).

    Five offsets (the default radius's row) in one pass: each ``d[i]`` loaded and stored once per
    five multiply-adds, the weights converted in registers; other counts offset by offset. A
    function of its own, not inlined: one compiled loop serves every caller (the compile time of
    an inlined copy per call site grew to minutes)."""
    m = d.shape[0]
    if n == _GROUP:
        w0, w1, w2, w3, w4 = w[k0, y, c0 : c0 + m], w[k0 + 1, y, c0 : c0 + m], w[k0 + 2, y, c0 : c0 + m], \
            w[k0 + 3, y, c0 : c0 + m], w[k0 + 4, y, c0 : c0 + m]
        for i in range(m):
            d[i] += (np.float32(w0[i]) * s[i] + np.float32(w1[i]) * s[i + 1] + np.float32(w2[i]) * s[i + 2]
                     + np.float32(w3[i]) * s[i + 3] + np.float32(w4[i]) * s[i + 4])
    else:
        for t in range(n):
            wt = w[k0 + t, y, c0 : c0 + m]
            for i in range(m):
                d[i] += np.float32(wt[i]) * s[i + t]


@njit(nogil=True, cache=True, fastmath={"contract"})
def gather_taps3(d0, d1, d2, w, k0, y, c0, s0, s1, s2):  # pragma: no cover - compiled
    """:func:`gather_taps` with five offsets on three channels at once: each weight is loaded and
    converted once for the three (about 0.6x the time of three calls)."""
    m = d0.shape[0]
    w0, w1, w2, w3, w4 = w[k0, y, c0 : c0 + m], w[k0 + 1, y, c0 : c0 + m], w[k0 + 2, y, c0 : c0 + m], \
        w[k0 + 3, y, c0 : c0 + m], w[k0 + 4, y, c0 : c0 + m]
    for i in range(m):
        b0, b1, b2 = np.float32(w0[i]), np.float32(w1[i]), np.float32(w2[i])
        b3, b4 = np.float32(w3[i]), np.float32(w4[i])
        d0[i] += b0 * s0[i] + b1 * s0[i + 1] + b2 * s0[i + 2] + b3 * s0[i + 3] + b4 * s0[i + 4]
        d1[i] += b0 * s1[i] + b1 * s1[i + 1] + b2 * s1[i + 2] + b3 * s1[i + 3] + b4 * s1[i + 4]
        d2[i] += b0 * s2[i] + b1 * s2[i + 1] + b2 * s2[i + 2] + b3 * s2[i + 3] + b4 * s2[i + 4]


@njit(nogil=True, cache=True, fastmath={"contract"})
def scatter_taps(d, w, k0, y, c0, s, n):  # pragma: no cover - compiled
    """``d[i] += sum_(t < n) w[k0 + t, y, c0 + i + n - 1 - t] * s[i + n - 1 - t]`` (``s``:
    ``len(d) + n - 1`` values starting at column ``c0``): the forward product's :func:`gather_taps`."""
    m = d.shape[0]
    if n == _GROUP:
        w0, w1, w2, w3, w4 = w[k0, y, c0 + 4 : c0 + 4 + m], w[k0 + 1, y, c0 + 3 : c0 + 3 + m], \
            w[k0 + 2, y, c0 + 2 : c0 + 2 + m], w[k0 + 3, y, c0 + 1 : c0 + 1 + m], w[k0 + 4, y, c0 : c0 + m]
        for i in range(m):
            d[i] += (np.float32(w0[i]) * s[i + 4] + np.float32(w1[i]) * s[i + 3] + np.float32(w2[i]) * s[i + 2]
                     + np.float32(w3[i]) * s[i + 1] + np.float32(w4[i]) * s[i])
    else:
        for t in range(n):
            u = n - 1 - t
            wt = w[k0 + t, y, c0 + u : c0 + u + m]
            for i in range(m):
                d[i] += np.float32(wt[i]) * s[i + u]


@njit(nogil=True, cache=True, fastmath={"contract"})
def scatter_taps3(d0, d1, d2, w, k0, y, c0, s0, s1, s2):  # pragma: no cover - compiled
    """:func:`scatter_taps` with five offsets on three channels at once."""
    m = d0.shape[0]
    w0, w1, w2, w3, w4 = w[k0, y, c0 + 4 : c0 + 4 + m], w[k0 + 1, y, c0 + 3 : c0 + 3 + m], \
        w[k0 + 2, y, c0 + 2 : c0 + 2 + m], w[k0 + 3, y, c0 + 1 : c0 + 1 + m], w[k0 + 4, y, c0 : c0 + m]
    for i in range(m):
        b0, b1, b2 = np.float32(w0[i]), np.float32(w1[i]), np.float32(w2[i])
        b3, b4 = np.float32(w3[i]), np.float32(w4[i])
        d0[i] += b0 * s0[i + 4] + b1 * s0[i + 3] + b2 * s0[i + 2] + b3 * s0[i + 1] + b4 * s0[i]
        d1[i] += b0 * s1[i + 4] + b1 * s1[i + 3] + b2 * s1[i + 2] + b3 * s1[i + 1] + b4 * s1[i]
        d2[i] += b0 * s2[i + 4] + b1 * s2[i + 3] + b2 * s2[i + 2] + b3 * s2[i + 1] + b4 * s2[i]


@njit(inline="always", cache=True)
def gather_edges(dst, w, k0, y, src, n, dx0, lo, hi):  # pragma: no cover - compiled
    """The columns of :func:`gather_group` outside ``[lo, hi)``, offset by offset (``lo = hi = 0``: all)."""
    width = dst.shape[0]
    for t in range(n):
        dx = dx0 + t
        for i in range(max(0, -dx), min(lo, width - dx)):
            dst[i] += np.float32(w[k0 + t, y, i]) * src[i + dx]
        for i in range(max(hi, -dx), min(width, width - dx)):
            dst[i] += np.float32(w[k0 + t, y, i]) * src[i + dx]


@njit(nogil=True, cache=True)
def gather_group(dst, w, k0, y, src, n, dx0):  # pragma: no cover - compiled
    """``dst[i] += sum_(t < n) w[k0 + t, y, i] * src[i + dx0 + t]`` where ``src`` has that pixel:
    the adjoint's share of offsets ``dx0 .. dx0 + n - 1`` of one ``dy`` (``dst``, ``src``: (W,))."""
    width = dst.shape[0]
    lo, hi = max(0, -dx0), min(width, width - (dx0 + n - 1))  # every offset of the group inside
    if hi > lo:
        gather_taps(dst[lo:hi], w, k0, y, lo, src[lo + dx0 : hi + dx0 + n - 1], n)
    else:
        lo = hi = 0
    gather_edges(dst, w, k0, y, src, n, dx0, lo, hi)


@njit(nogil=True, cache=True)
def gather_group3(d0, d1, d2, w, k0, y, s0, s1, s2, n, dx0):  # pragma: no cover - compiled
    """:func:`gather_group` for three channels, five offsets at once through :func:`gather_taps3`."""
    width = d0.shape[0]
    lo, hi = max(0, -dx0), min(width, width - (dx0 + n - 1))
    if n != _GROUP or hi <= lo:
        gather_group(d0, w, k0, y, s0, n, dx0)
        gather_group(d1, w, k0, y, s1, n, dx0)
        gather_group(d2, w, k0, y, s2, n, dx0)
        return
    b, e = lo + dx0, hi + dx0 + n - 1
    gather_taps3(d0[lo:hi], d1[lo:hi], d2[lo:hi], w, k0, y, lo, s0[b:e], s1[b:e], s2[b:e])
    gather_edges(d0, w, k0, y, s0, n, dx0, lo, hi)
    gather_edges(d1, w, k0, y, s1, n, dx0, lo, hi)
    gather_edges(d2, w, k0, y, s2, n, dx0, lo, hi)


@njit(inline="always", cache=True)
def scatter_edges(dst, w, k0, y, src, n, dx0, lo, hi):  # pragma: no cover - compiled
    """The columns of :func:`scatter_group` outside ``[lo, hi)``, offset by offset (``lo = hi = 0``: all)."""
    width = dst.shape[0]
    for t in range(n):
        dx = dx0 + t
        for o in range(max(0, dx), min(lo, width + dx)):
            dst[o] += np.float32(w[k0 + t, y, o - dx]) * src[o - dx]
        for o in range(max(hi, dx), min(width, width + dx)):
            dst[o] += np.float32(w[k0 + t, y, o - dx]) * src[o - dx]


@njit(nogil=True, cache=True)
def scatter_group(dst, w, k0, y, src, n, dx0):  # pragma: no cover - compiled
    """``dst[o] += sum_(t < n) w[k0 + t, y, o - dx] * src[o - dx]`` (``dx = dx0 + t``) where the
    source pixel exists: the light of one content row ``src`` through offsets ``dx0 .. dx0 + n - 1``
    of one ``dy``, onto camera row ``dst`` (both (W,))."""
    width = dst.shape[0]
    lo, hi = max(0, dx0 + n - 1), min(width, width + dx0)  # every offset of the group has its source
    if hi > lo:
        c0 = lo - dx0 - (n - 1)  # the source column of the last offset at camera column lo
        scatter_taps(dst[lo:hi], w, k0, y, c0, src[c0 : hi - dx0], n)
    else:
        lo = hi = 0
    scatter_edges(dst, w, k0, y, src, n, dx0, lo, hi)


@njit(nogil=True, cache=True)
def scatter_group3(d0, d1, d2, w, k0, y, s0, s1, s2, n, dx0):  # pragma: no cover - compiled
    """:func:`scatter_group` for three channels, five offsets at once through :func:`scatter_taps3`."""
    width = d0.shape[0]
    lo, hi = max(0, dx0 + n - 1), min(width, width + dx0)
    if n != _GROUP or hi <= lo:
        scatter_group(d0, w, k0, y, s0, n, dx0)
        scatter_group(d1, w, k0, y, s1, n, dx0)
        scatter_group(d2, w, k0, y, s2, n, dx0)
        return
    c0 = lo - dx0 - (n - 1)
    scatter_taps3(d0[lo:hi], d1[lo:hi], d2[lo:hi], w, k0, y, c0, s0[c0 : hi - dx0], s1[c0 : hi - dx0],
                  s2[c0 : hi - dx0])
    scatter_edges(d0, w, k0, y, s0, n, dx0, lo, hi)
    scatter_edges(d1, w, k0, y, s1, n, dx0, lo, hi)
    scatter_edges(d2, w, k0, y, s2, n, dx0, lo, hi)


@njit(nogil=True, cache=True)
def adjoint_row(dst, w, v, y, radius):  # pragma: no cover - compiled
    """``dst = sum_(dy,dx) w_(dy,dx)[y] * v[y + dy, . + dx]``, unscaled: content row ``y`` of
    ``L^T v`` from its weight row; ``v``: (H, W) one channel's camera image."""
    h = w.shape[1]
    side = 2 * radius + 1
    for i in range(dst.shape[0]):
        dst[i] = np.float32(0.0)
    for dy in range(-radius, radius + 1):
        yy = y + dy
        if 0 <= yy < h:
            dx0 = -radius
            while dx0 <= radius:
                n = min(_GROUP, radius - dx0 + 1)
                gather_group(dst, w, (dy + radius) * side + dx0 + radius, y, v[yy], n, dx0)
                dx0 += n


@njit(nogil=True, cache=True)
def adjoint_row3(d0, d1, d2, w, v, y, radius):  # pragma: no cover - compiled
    """:func:`adjoint_row` for the three channels of ``v`` (3, H, W) at once, into ``d0, d1, d2``."""
    h = w.shape[1]
    side = 2 * radius + 1
    for i in range(d0.shape[0]):
        d0[i] = d1[i] = d2[i] = np.float32(0.0)
    for dy in range(-radius, radius + 1):
        yy = y + dy
        if 0 <= yy < h:
            dx0 = -radius
            while dx0 <= radius:
                n = min(_GROUP, radius - dx0 + 1)
                gather_group3(d0, d1, d2, w, (dy + radius) * side + dx0 + radius, y, v[0, yy], v[1, yy], v[2, yy],
                              n, dx0)
                dx0 += n


@njit(nogil=True, cache=True)
def adjoint_rows(w, scale, v, out, y0, y1, radius):  # pragma: no cover - compiled
    """``out[c, y - y0] = (L^T v[c])[y]`` for content rows ``y`` in ``[y0, y1)``.

    ``w``: (K, H, W) weights (all rows); ``scale``: float32; ``v``: (C, H, W) float32 camera
    images; ``out``: (C, y1 - y0, W) float32, overwritten. Three channels go together.
    """
    width = w.shape[2]
    n_ch = v.shape[0]
    for y in range(y0, y1):
        if n_ch == 3:
            adjoint_row3(out[0, y - y0], out[1, y - y0], out[2, y - y0], w, v, y, radius)
        for ch in range(n_ch):
            row = out[ch, y - y0]
            if n_ch != 3:
                adjoint_row(row, w, v[ch], y, radius)
            if scale != 1.0:
                for i in range(width):
                    row[i] *= scale


@njit(inline="always", cache=True)
def _add_entry(w, k, yj, xj, value, quantize, inv_scale):  # pragma: no cover - compiled
    """``w[k, yj, xj] += value`` (``uint16``: its rounded steps); False when it leaves ``uint16``'s range."""
    if quantize:
        q = np.rint(value * inv_scale) + w[k, yj, xj]
        if not 0.0 <= q <= 65535.0:  # also refuses NaN
            return False
        w[k, yj, xj] = q
    else:
        w[k, yj, xj] += value
    return True


@njit(nogil=True, cache=True)
def _extract_entries(indptr, indices, data, w, i0, i1, radius, quantize, inv_scale):  # pragma: no cover - compiled
    """:func:`extract_rows` entry by entry for camera pixels ``[i0, i1)``: any order, duplicates summed."""
    _, h, width = w.shape
    side = 2 * radius + 1
    shift = radius + 1
    inv_width = 1.0 / width
    for i in range(i0, i1):
        yi = i // width
        xi = i - yi * width
        for p in range(indptr[i], indptr[i + 1]):
            d = i - indices[p]  # dy * W + dx
            # dy without an integer division: (d + R + 0.5) / W is never within 0.5 / W of an integer,
            # so float64 rounding cannot move the floor (shifted positive, so truncation is the floor)
            dy = int((d + radius + 0.5) * inv_width + shift) - shift
            dx = d - dy * width
            yj = yi - dy
            xj = xi - dx
            if dy < -radius or dy > radius or dx < -radius or dx > radius or not (0 <= yj < h and 0 <= xj < width):
                return False
            if not _add_entry(w, (dy + radius) * side + dx + radius, yj, xj, data[p], quantize, inv_scale):
                return False
    return True


_RUN = 64  # camera pixels whose windows are checked and copied as one block


@njit(nogil=True, cache=True)
def extract_rows(indptr, indices, data, w, y0, y1, radius, quantize, inv_scale):  # pragma: no cover - compiled
    """Copy camera rows ``[y0, y1)`` of the CSR matrix ``(indptr, indices, data)`` into ``w``; False
    as soon as an entry does not fit.

    Row ``i`` (camera pixel ``(yi, xi)``) and column ``j`` (content pixel ``(yj, xj)``) of ``L`` on
    the ``(H, W)`` grid of ``w`` (K, H, W) hold ``w_(dy,dx)[yj, xj]`` with ``(dy, dx) = (yi - yj,
    xi - xj)``; an entry fits when ``|dy|, |dx| <= radius`` (so no window wraps across a row).
    ``w`` float32 takes the values as they are; ``uint16`` (``quantize`` True) takes
    ``rint(value * inv_scale)`` and refuses a negative value or one beyond 65535 steps. ``w`` must
    be zero on entry. Calls on separate row ranges may run on separate threads: each
    ``(k, yj, xj)`` belongs to one camera pixel.

    A run of ``_RUN`` interior pixels whose rows hold exactly the ``K`` window columns in CSR's
    sorted order (the common case) is checked by one vectorised comparison against that pattern
    and copied offset by offset (a blocked transpose); every other pixel goes entry by entry
    (:func:`_extract_entries`).
    """
    n_k, h, width = w.shape
    side = 2 * radius + 1
    pattern = np.empty(_RUN * n_k, dtype=indices.dtype)  # columns of a run of full windows, less its first row
    for q in range(_RUN):
        for t in range(n_k):  # columns ascending = offsets descending
            k = n_k - 1 - t
            pattern[q * n_k + t] = q - ((k // side - radius) * width + k % side - radius)
    for y in range(y0, y1):
        row0 = y * width
        if y < radius or y >= h - radius:
            if not _extract_entries(indptr, indices, data, w, row0, row0 + width, radius, quantize, inv_scale):
                return False
            continue
        if not (_extract_entries(indptr, indices, data, w, row0, row0 + radius, radius, quantize, inv_scale)
                and _extract_entries(indptr, indices, data, w, row0 + width - radius, row0 + width, radius,
                                     quantize, inv_scale)):
            return False
        x = radius
        while x < width - radius:
            m = min(_RUN, width - radius - x)
            i = row0 + x
            s = np.int64(indptr[i])
            full = np.int64(indptr[i + m]) - s == m * n_k
            if full:
                cols = indices[s : s + m * n_k]
                bad = 0
                for t in range(m * n_k):
                    bad |= (cols[t] - i) ^ pattern[t]
                full = bad == 0
            if not full:
                if not _extract_entries(indptr, indices, data, w, i, i + m, radius, quantize, inv_scale):
                    return False
            else:
                vals = data[s : s + m * n_k]
                for t in range(n_k):
                    k = n_k - 1 - t
                    dy = k // side - radius
                    dx = k % side - radius
                    dst = w[k, y - dy, x - dx : x - dx + m]
                    if quantize:
                        fits = True
                        for q in range(m):
                            v = np.rint(vals[q * n_k + t] * inv_scale)
                            fits &= 0.0 <= v <= 65535.0
                            dst[q] = v
                        if not fits:
                            return False
                    else:
                        for q in range(m):
                            dst[q] = vals[q * n_k + t]
            x += m
    return True


@njit(nogil=True, cache=True)
def scatter_rows(w, scale, x, y0, y1, radius, sink, r0, r1):  # pragma: no cover - compiled
    """Add the light of content rows ``[y0, y1)`` that lands on camera rows ``[r0, r1)``:
    ``sink[c, yy - r0] += (L[:, rows] x[c])[yy]``.

    ``w``: (K, H, W) weights (all rows); ``scale``: float32; ``x``: (C, y1 - y0, W) float32
    content rows; ``sink``: (C, r1 - r0, W) float32, accumulated into.
    """
    h, width = w.shape[1], w.shape[2]
    side = 2 * radius + 1
    lo = max(r0, 0)
    hi = min(r1, h)
    n_ch = x.shape[0]
    src = np.empty((n_ch, width), dtype=np.float32)  # the rows times scale, as the OpenCV loop scaled x first
    for y in range(y0, y1):
        for ch in range(n_ch):
            row = x[ch, y - y0]
            for i in range(width):
                src[ch, i] = row[i] * scale
        for dy in range(-radius, radius + 1):
            yy = y + dy
            if lo <= yy < hi:
                dx0 = -radius
                while dx0 <= radius:
                    n = min(_GROUP, radius - dx0 + 1)
                    k = (dy + radius) * side + dx0 + radius
                    if n_ch == 3:
                        scatter_group3(sink[0, yy - r0], sink[1, yy - r0], sink[2, yy - r0], w, k, y, src[0], src[1],
                                       src[2], n, dx0)
                    else:
                        for ch in range(n_ch):
                            scatter_group(sink[ch, yy - r0], w, k, y, src[ch], n, dx0)
                    dx0 += n


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def update_row(gr, xk, xo, light, scale, step, beta):  # pragma: no cover - compiled
    """One row of the APG update: ``xo = clip(y - step * scale * gr, 0, 1)`` with
    ``y = xk + beta (xk - xo)`` (``xo`` holds ``x_{k-1}`` on entry, ``x_{k+1}`` on return) and
    ``light = xo * scale``. Returns ``(sum min(0, scale gr), ||y - xo||^2, <y - xo, xo - xk>)``.

    Written to vectorise: the sum of the negative gradients is branch-free (``min(0, g)``; a
    conditional sum kept the loop scalar, 3x slower), and ``x_{k-1}`` is read and ``x_{k+1}``
    written through the one array ``xo`` (inside the sweep, two views of the same row, which a
    runtime overlap check cannot pass). Together about 20 % of a sweep at 2592x1944."""
    zero, one = np.float32(0.0), np.float32(1.0)
    one_b = one + beta
    gneg = ymx = inner = 0.0
    if beta == 0:  # the first iteration: there is no x_{k-1} (xo may hold anything); y = x_k exactly
        xo[:] = xk
    for i in range(gr.shape[0]):
        gi = gr[i] * scale
        gneg += min(gi, zero)
        xc = xk[i]
        yi = one_b * xc - beta * xo[i]
        xn = min(max(yi - step * gi, zero), one)
        xo[i] = xn
        d = yi - xn
        ymx += d * d
        inner += d * (xn - xc)
        light[i] = xn * scale  # scaled as the products scale x
    return gneg, ymx, inner


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def sweep_rows(w, scale, radius, c, x_cur, x_prev, lx_cur, lx_prev, res, step, beta, y0, y1, lo, hi,
               halo_top, halo_bot, g, light):  # pragma: no cover - compiled
    """Rows ``[y0, y1)`` of one APG iteration (the module docstring of :mod:`.stencil_apg`).

    Assembles ``res = Lx_k + beta (Lx_k - Lx_{k-1}) - c`` on camera rows ``[lo, hi)`` (the rows
    within ``R`` of a shared boundary are the caller's), computes ``g = L^T res`` and
    ``x_{k+1} = clip(y - step g, 0, 1)`` with ``y = x_k + beta (x_k - x_{k-1})`` into ``x_prev``,
    and accumulates ``L x_{k+1}`` over ``lx_prev`` (zeroed just after its old rows were
    assembled); light thrown above ``y0`` goes to ``halo_top`` (camera rows ``[y0 - R, y0)``),
    below ``y1`` to ``halo_bot`` (rows ``[y1, ...)``). ``g`` (the row's gradient) and ``light``
    (its ``x_{k+1}`` times ``scale``, what the forward product scatters): (C, W) float32 scratch.

    Returns ``(sum min(0, g), ||y - x_{k+1}||^2, <y - x_{k+1}, x_{k+1} - x_k>,
    ||Lx_{k+1} - c||^2 on rows [lo, hi), ||res||^2, <res, c>)``.
    """
    h, width = w.shape[1], w.shape[2]
    side = 2 * radius + 1
    n_ch = c.shape[0]
    one_b = np.float32(1.0) + beta
    zero = np.float32(0.0)
    gneg = ymx = inner = f = rr = rc = 0.0
    assembled, zeroed, finished = lo, y0, lo
    top0 = y0 - radius
    for y in range(y0, y1):
        upto = min(y + radius + 1, hi)
        while assembled < upto:  # 1. the residual, R rows ahead of the adjoint that reads it
            for ch in range(n_ch):
                rrow, lc, cr = res[ch, assembled], lx_cur[ch, assembled], c[ch, assembled]
                lp = lc if beta == 0 else lx_prev[ch, assembled]  # beta = 0: Lx_{k-1} unread (none at k = 0)
                for i in range(width):
                    v = one_b * lc[i] - beta * lp[i] - cr[i]
                    rrow[i] = v
                    rr += v * v
                    rc += v * cr[i]
            assembled += 1
        if n_ch == 3:  # 2. g = L^T res on row y (three channels at once)
            adjoint_row3(g[0], g[1], g[2], w, res, y, radius)
        for ch in range(n_ch):
            gr = g[ch]
            if n_ch != 3:
                adjoint_row(gr, w, res[ch], y, radius)
            a, b, c_ = update_row(gr, x_cur[ch, y], x_prev[ch, y], light[ch], scale, step, beta)  # 3. the update
            gneg += a
            ymx += b
            inner += c_
        z = min(y + radius + 1, y1)  # Lx_{k-1} on these rows is assembled: they start Lx_{k+1}
        while zeroed < z:
            for ch in range(n_ch):
                lz = lx_prev[ch, zeroed]
                for i in range(width):
                    lz[i] = zero
            zeroed += 1
        for dy in range(-radius, radius + 1):  # 4. the light of row y, from the weight row the adjoint just read
            yy = y + dy
            if yy < 0 or yy >= h:
                continue
            if yy < y0:
                dst, row = halo_top, yy - top0
            elif yy >= y1:
                dst, row = halo_bot, yy - y1
            else:
                dst, row = lx_prev, yy
            dx0 = -radius
            while dx0 <= radius:
                n = min(_GROUP, radius - dx0 + 1)
                k = (dy + radius) * side + dx0 + radius
                if n_ch == 3:
                    scatter_group3(dst[0, row], dst[1, row], dst[2, row], w, k, y, light[0], light[1], light[2], n, dx0)
                else:
                    for ch in range(n_ch):
                        scatter_group(dst[ch, row], w, k, y, light[ch], n, dx0)
                dx0 += n
        done = hi if y == y1 - 1 else min(y - radius + 1, hi)  # no later row reaches rows above y - R
        while finished < done:  # 5. the objective on final rows
            for ch in range(n_ch):
                lr, cr = lx_prev[ch, finished], c[ch, finished]
                for i in range(width):
                    d = lr[i] - cr[i]
                    f += d * d
            finished += 1
    return gneg, ymx, inner, f, rr, rc
