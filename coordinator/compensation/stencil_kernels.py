"""The two products of the stencil storage, compiled: every offset of a row in one pass.

:mod:`.stencil` defines ``L`` by ``K = (2R+1)^2`` weight images ``w_(dy,dx)`` (row-major offsets,
``k = (dy + R) * (2R+1) + (dx + R)``) and ``scale`` (one ``uint16`` step, 1.0 for float32)::

    (L x)[y + dy, x + dx] += scale * w_(dy,dx)[y, x] * x[y, x]
    (L^T v)[y, x]          = scale * sum_(dy,dx) w_(dy,dx)[y, x] * v[y + dy, x + dx]

OpenCV needs one ``accumulateProduct`` per offset and channel over a whole band, and a ``uint16``
band must first be converted to float32 in a separate pass. Here, per weight row, Numba's loop
over the row's pixels reads the ``uint16`` (or float32) weights once, converts them in registers
and accumulates into output rows that stay in the core's first-level cache; LLVM vectorises the
inner loop (it is a plain ``a[i] += w[i] * b[i]`` over unit-stride slices, indexed from 0 so no
negative-index check blocks it). The kernels release the GIL, so the solver's threads run them on
separate row ranges at once.

The sums are the OpenCV loop's in float32; only their order per output pixel may differ (and
with it the last bits). The tests compare both products against SciPy's CSR product of the same
matrix.

Shapes: ``w`` (K, H, W) uint16 or float32; images (C, rows, W) float32 with unit-stride rows.
The first call of each kernel for a new combination of argument types compiles it (a few seconds);
the machine code is cached beside this module for the next process.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["adjoint_rows", "scatter_rows"]


@njit(nogil=True, cache=True)
def adjoint_rows(w, scale, v, out, y0, y1, radius):  # pragma: no cover - compiled
    """``out[c, y - y0] = (L^T v[c])[y]`` for content rows ``y`` in ``[y0, y1)``.

    ``w``: (K, H, W) weights (all rows); ``scale``: float32; ``v``: (C, H, W) float32 camera
    images; ``out``: (C, y1 - y0, W) float32, overwritten.
    """
    n_k, h, width = w.shape
    side = 2 * radius + 1
    zero = np.float32(0.0)
    for ch in range(v.shape[0]):
        for y in range(y0, y1):
            row = out[ch, y - y0]
            for i in range(width):
                row[i] = zero
            for k in range(n_k):
                dy = k // side - radius
                dx = k % side - radius
                yy = y + dy
                if yy < 0 or yy >= h:
                    continue
                c0 = max(0, -dx)
                c1 = min(width, width - dx)
                ws = w[k, y, c0:c1]
                vs = v[ch, yy, c0 + dx : c1 + dx]
                os = row[c0:c1]
                for i in range(c1 - c0):
                    os[i] += np.float32(ws[i]) * vs[i]
            if scale != 1.0:
                for i in range(width):
                    row[i] *= scale


@njit(nogil=True, cache=True)
def scatter_rows(w, scale, x, y0, y1, radius, sink, r0, r1):  # pragma: no cover - compiled
    """Add the light of content rows ``[y0, y1)`` that lands on camera rows ``[r0, r1)``:
    ``sink[c, yy - r0] += (L[:, rows] x[c])[yy]``.

    ``w``: (K, H, W) weights (all rows); ``scale``: float32; ``x``: (C, y1 - y0, W) float32
    content rows; ``sink``: (C, r1 - r0, W) float32, accumulated into.
    """
    n_k, h, width = w.shape
    side = 2 * radius + 1
    lo = max(r0, 0)
    hi = min(r1, h)
    src = np.empty(width, dtype=np.float32)  # the row times scale, as the OpenCV loop scaled x first
    for ch in range(x.shape[0]):
        for y in range(y0, y1):
            row = x[ch, y - y0]
            for i in range(width):
                src[i] = row[i] * scale
            for k in range(n_k):
                dy = k // side - radius
                dx = k % side - radius
                yy = y + dy
                if yy < lo or yy >= hi:
                    continue
                c0 = max(0, -dx)
                c1 = min(width, width - dx)
                ws = w[k, y, c0:c1]
                xs = src[c0:c1]
                os = sink[ch, yy - r0, c0 + dx : c1 + dx]
                for i in range(c1 - c0):
                    os[i] += np.float32(ws[i]) * xs[i]
