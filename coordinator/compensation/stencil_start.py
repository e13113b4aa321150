"""A cold start for the stencil solver: the target deconvolved by the rig's mean blur.

FISTA from the target itself (``x_0 = clip(c)``) spends most of its iterations on the high
spatial frequencies, which the blur passes weakly; the low ones settle in a few iterations, so
a start from a coarser solve gains nothing (measured: 40 iterations to 1 % of the optimum from
either start at 960x540, 25 projectors). What does gain is a start that already holds the high
frequencies: the target divided by the blur's transfer function. On a shared grid ``L`` is a
spatially varying convolution, ``(L x)[i] = sum_k w_k[i - off_k] x[i - off_k]``; its mean kernel
``h[dy, dx] = mean_j w_(dy,dx)[j]`` is a convolution whose inverse is one Wiener filter in the
Fourier domain::

    x_0 = clip(F^-1[ conj(H) C / (|H|^2 + lam |H(0)|^2) ], 0, 1)

with ``H`` the transfer function of ``h`` and ``lam`` a small relative regulariser (the kernel's
weak frequencies would otherwise amplify noise and the spatial variation of ``L`` that the mean
ignores). The start is only a start: the bounded solve that follows is unchanged and converges
to the same optimum. Cost: two real FFTs of the image per channel (about two iterations' worth at
2592x1944); the FFT treats the image as periodic, which only makes the start worse near the edges.
"""
from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from coordinator.compensation.stencil import StencilTransport

__all__ = ["LAMBDA", "deconvolved_start", "mean_kernel"]

#: Wiener regulariser relative to ``|H(0)|^2`` (measured at 960x540: 1e-4 ... 3e-3 all cut the
#: iterations to 1 % of the optimum from 40 to 24-27; 1e-3 was the best)
LAMBDA = 1e-3
_SAMPLE = 8  # every 8th row and column of the weights estimates the mean kernel (a 64th of their bytes)


def mean_kernel(st: StencilTransport) -> np.ndarray:
    """``h``: (2R+1, 2R+1) float64, ``h[dy + R, dx + R]`` the mean of ``w_(dy,dx)`` over a grid sample.

    Cached on ``st`` (the weights never change once built).
    """
    h = getattr(st, "_mean_kernel", None)
    if h is None:
        side = 2 * st.radius + 1
        sample = st.weights[:, ::_SAMPLE, ::_SAMPLE]
        h = sample.reshape(side * side, -1).mean(axis=1, dtype=np.float64).reshape(side, side) * st.scale
        st._mean_kernel = h
    return h


def _transfer(h: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``H`` on the ``rfft2`` grid of ``shape``: (H, W // 2 + 1) complex64, ``h`` centred at the origin.

    ``H[u, v] = sum_(dy,dx) h[dy, dx] exp(-2 pi i (u dy / H + v dx / W))``: two small matrix products.
    """
    rows, cols = shape
    r = (h.shape[0] - 1) // 2
    d = np.arange(-r, r + 1)
    ey = np.exp(-2j * np.pi * np.outer(np.arange(rows), d) / rows)  # (H, 2R+1)
    ex = np.exp(-2j * np.pi * np.outer(d, np.arange(cols // 2 + 1)) / cols)  # (2R+1, W//2+1)
    return (ey @ h).astype(np.complex64) @ ex.astype(np.complex64)


def _filter(st: StencilTransport, lam: float) -> np.ndarray:
    """``conj(H) / (|H|^2 + lam |H(0)|^2)`` on ``rfft2``'s grid, complex64; cached on ``st`` per ``lam``."""
    cached = getattr(st, "_start_filter", None)
    if cached is not None and cached[0] == lam:
        return cached[1]
    g = _transfer(mean_kernel(st), st.grid)
    dc = float(abs(g[0, 0])) ** 2
    den = np.square(g.real)
    den += np.square(g.imag)
    den += np.float32(lam * max(dc, 1e-30))
    np.conjugate(g, out=g)
    g /= den
    st._start_filter = (lam, g)
    return g


def deconvolved_start(st: StencilTransport, c: np.ndarray, *, lam: float = LAMBDA, workers: int = 1) -> np.ndarray:
    """The Wiener-deconvolved target, clipped to [0, 1].

    ``c``: (n, C) float32 target on ``st``'s grid (pixel-major, as the solver holds it);
    returns (n, C) float32, C-contiguous. ``workers``: threads of the FFTs.
    """
    rows, cols = st.grid
    nc = c.shape[1]
    g = _filter(st, lam)
    out = None if nc == 1 else np.empty((rows * cols, nc), dtype=np.float32)
    for ch in range(nc):
        img = np.ascontiguousarray(c[:, ch].reshape(rows, cols), dtype=np.float32)
        spec = sfft.rfft2(img, workers=workers)
        spec *= g
        x = sfft.irfft2(spec, s=(rows, cols), workers=workers, overwrite_x=True)
        np.clip(x, 0, 1, out=x)
        if out is None:
            return x.reshape(-1, 1)  # one channel: the transform's own fresh array, no copy
        out[:, ch] = x.reshape(-1)
    return out
