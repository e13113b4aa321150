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

A warm-started video frame needs less (``radius``): it starts from the new frame's deconvolved
target plus the previous frame's correction *relative to the previous deconvolved target*, so an
approximate deconvolution, used the same way on every frame, is absorbed by the carried
correction. The Wiener filter's own kernel, cut to ``(2r+1) x (2r+1)`` taps around its centre and
applied in the image domain (``cv2.filter2D``, edges reflected), is such an approximation at a
fraction of the FFTs' cost. Measured at 960x540, 25 projectors, PSF radius 2, 4 warm iterations
(``bench compensation``'s clips): cut at r = 3 or 4 the largest shortfall from converged stayed
0.41 / 0.46 dB (pan / overlay), as with the FFTs; at r = 2 the pan's grew to 0.46.
"""
from __future__ import annotations

import cv2
import numpy as np
import scipy.fft as sfft

from imaging.compensation.stencil import StencilTransport

__all__ = ["LAMBDA", "deconvolved_start", "mean_kernel", "wiener_kernel"]

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


def wiener_kernel(st: StencilTransport, radius: int, lam: float = LAMBDA) -> np.ndarray:
    """The Wiener filter's spatial kernel cut to ``(2 radius + 1)`` taps a side, as ``cv2.filter2D``
    applies it: (k, k) float32, centred and mirrored (``filter2D`` correlates; the FFTs convolve).
    Its full extent is the image's: the inverse FFT of :func:`_filter`'s grid. Cached on ``st``
    per ``(radius, lam)``."""
    if radius < 1:
        raise ValueError(f"radius must be >= 1, got {radius}")
    cached = getattr(st, "_start_kernel", None)
    if cached is not None and cached[0] == (radius, lam):
        return cached[1]
    rows, cols = st.grid
    full = sfft.irfft2(_filter(st, lam), s=(rows, cols))   # the kernel at the origin, wrapped around
    r = min(radius, (rows - 1) // 2, (cols - 1) // 2)
    taps = -np.arange(-r, r + 1)   # mirrored: tap i of the correlation is the convolution's -i
    kernel = np.ascontiguousarray(full[np.ix_(taps % rows, taps % cols)], dtype=np.float32)
    st._start_kernel = ((radius, lam), kernel)
    return kernel


def deconvolved_start(st: StencilTransport, c: np.ndarray, *, lam: float = LAMBDA, workers: int = 1,
                      radius: int | None = None) -> np.ndarray:
    """The Wiener-deconvolved target, clipped to [0, 1].

    ``c``: (n, C) float32 target on ``st``'s grid (pixel-major, as the solver holds it);
    returns (n, C) float32, C-contiguous. ``workers``: threads of the FFTs. ``radius``: apply the
    filter's kernel cut to that many taps each way in the image domain instead of the FFTs (see
    the module docstring; edges reflected, not wrapped).
    """
    rows, cols = st.grid
    nc = c.shape[1]
    g = _filter(st, lam) if radius is None else wiener_kernel(st, radius, lam)
    out = None if nc == 1 else np.empty((rows * cols, nc), dtype=np.float32)
    for ch in range(nc):
        img = np.ascontiguousarray(c[:, ch].reshape(rows, cols), dtype=np.float32)
        if radius is None:
            spec = sfft.rfft2(img, workers=workers)
            spec *= g
            x = sfft.irfft2(spec, s=(rows, cols), workers=workers, overwrite_x=True)
        else:
            x = cv2.filter2D(img, -1, g, borderType=cv2.BORDER_REFLECT)
        np.clip(x, 0, 1, out=x)
        if out is None:
            return x.reshape(-1, 1)  # one channel: a fresh array, no copy
        out[:, ch] = x.reshape(-1)
    return out
