"""One thread's sweep of :mod:`.stencil_apg`, compiled, one content row at a time.

The Python sweep works on bands of rows, and between its two products the band's weights had to
wait in a cache the band barely fits. Here each row goes through all four steps of the sweep
before the next starts (assemble the residual ``R`` rows ahead, the adjoint of the row, its
update, and its light scattered onto the ``2R + 1`` camera rows it reaches), so the weight row the
adjoint read is still in the first-level cache when the scatter reads it again: ``L`` streams
from memory once per iteration.

Arrays are (C, H, W) float32 images with unit-stride rows unless stated; ``w`` (K, H, W) float32
or uint16 weights as in :mod:`.stencil`. Partial sums are float64. The kernel may reassociate sums
and fuse multiply-adds (``fastmath`` reassoc and contract, nothing that assumes finite values), so
the sums' loops vectorise too (about 10 % faster at 2592x1944); the iterates differ from the
plain loop's only in float32's last bits.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["sweep_rows"]


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def sweep_rows(w, scale, radius, c, x_cur, x_prev, lx_cur, lx_prev, res, step, beta, y0, y1, lo, hi,
               halo_top, halo_bot, g, yv):  # pragma: no cover - compiled
    """Rows ``[y0, y1)`` of one APG iteration (the module docstring of :mod:`.stencil_apg`).

    Assembles ``res = Lx_k + beta (Lx_k - Lx_{k-1}) - c`` on camera rows ``[lo, hi)`` (the rows
    within ``R`` of a shared boundary are the caller's), computes ``g = L^T res`` and
    ``x_{k+1} = clip(y - step g, 0, 1)`` with ``y = x_k + beta (x_k - x_{k-1})`` into ``x_prev``,
    and accumulates ``L x_{k+1}`` over ``lx_prev`` (zeroed just after its old rows were
    assembled); light thrown above ``y0`` goes to ``halo_top`` (camera rows ``[y0 - R, y0)``),
    below ``y1`` to ``halo_bot`` (rows ``[y1, ...)``). ``g``, ``yv``: (C, W) float32 scratch.

    Returns ``(sum min(0, g), ||y - x_{k+1}||^2, <y - x_{k+1}, x_{k+1} - x_k>,
    ||Lx_{k+1} - c||^2 on rows [lo, hi), ||res||^2, <res, c>)``.
    """
    n_k, h, width = w.shape
    side = 2 * radius + 1
    n_ch = c.shape[0]
    one_b = np.float32(1.0) + beta
    zero = np.float32(0.0)
    one = np.float32(1.0)
    gneg = ymx = inner = f = rr = rc = 0.0
    assembled, zeroed, finished = lo, y0, lo
    top0 = y0 - radius
    for y in range(y0, y1):
        upto = min(y + radius + 1, hi)
        while assembled < upto:  # 1. the residual, R rows ahead of the adjoint that reads it
            for ch in range(n_ch):
                rrow, lc, lp, cr = res[ch, assembled], lx_cur[ch, assembled], lx_prev[ch, assembled], c[ch, assembled]
                for i in range(width):
                    v = one_b * lc[i] - beta * lp[i] - cr[i]
                    rrow[i] = v
                    rr += v * v
                    rc += v * cr[i]
            assembled += 1
        for ch in range(n_ch):  # 2. g = L^T res on row y
            gr = g[ch]
            for i in range(width):
                gr[i] = zero
            for k in range(n_k):
                yy = y + k // side - radius
                if yy < 0 or yy >= h:
                    continue
                dx = k % side - radius
                c0 = max(0, -dx)
                c1 = min(width, width - dx)
                ws = w[k, y, c0:c1]
                vs = res[ch, yy, c0 + dx : c1 + dx]
                gs = gr[c0:c1]
                for i in range(c1 - c0):
                    gs[i] += np.float32(ws[i]) * vs[i]
            for i in range(width):  # 3. the update of row y, over x_{k-1}
                gi = gr[i] * scale
                if gi < 0:
                    gneg += gi
                xc = x_cur[ch, y, i]
                yi = one_b * xc - beta * x_prev[ch, y, i]
                xn = min(max(yi - step * gi, zero), one)
                x_prev[ch, y, i] = xn
                d = yi - xn
                ymx += d * d
                inner += d * (xn - xc)
                yv[ch, i] = xn * scale  # the row's light source, scaled as the products scale x
        z = min(y + radius + 1, y1)  # Lx_{k-1} on these rows is assembled: they start Lx_{k+1}
        while zeroed < z:
            for ch in range(n_ch):
                lz = lx_prev[ch, zeroed]
                for i in range(width):
                    lz[i] = zero
            zeroed += 1
        for k in range(n_k):  # 4. the light of row y, from the weight row the adjoint just read
            yy = y + k // side - radius
            if yy < 0 or yy >= h:
                continue
            dx = k % side - radius
            c0 = max(0, -dx)
            c1 = min(width, width - dx)
            ws = w[k, y, c0:c1]
            for ch in range(n_ch):
                if yy < y0:
                    dst = halo_top[ch, yy - top0, c0 + dx : c1 + dx]
                elif yy >= y1:
                    dst = halo_bot[ch, yy - y1, c0 + dx : c1 + dx]
                else:
                    dst = lx_prev[ch, yy, c0 + dx : c1 + dx]
                src = yv[ch, c0:c1]
                for i in range(c1 - c0):
                    dst[i] += np.float32(ws[i]) * src[i]
        done = hi if y == y1 - 1 else min(y - radius + 1, hi)  # no later row reaches rows above y - R
        while finished < done:  # 5. the objective on final rows
            for ch in range(n_ch):
                lr, cr = lx_prev[ch, finished], c[ch, finished]
                for i in range(width):
                    d = lr[i] - cr[i]
                    f += d * d
            finished += 1
    return gneg, ymx, inner, f, rr, rc
