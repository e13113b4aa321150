"""The stencil solver's cold start: a Wiener deconvolution by the mean kernel, against NumPy's FFT,
SciPy's convolution and the bounded optimum of scipy.optimize.lsq_linear."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from imaging.compensation.solver import (
    FrameCompensator,
    TransportOperator,
    objective,
    solve,
)
from imaging.compensation.stencil import StencilTransport, stencil_from_csr
from imaging.compensation.stencil_start import (
    _transfer,
    deconvolved_start,
    mean_kernel,
    wiener_kernel,
)
from imaging.compensation.synthetic import sample_image, synthetic_rig, synthetic_transport

SHAPE = (24, 30)


@pytest.fixture(scope="module")
def L():
    return synthetic_transport(synthetic_rig(9, content_shape=SHAPE, radius=2, seed=5), scale=1 / 9)


def test_mean_kernel_and_its_transfer_function(L):
    st = stencil_from_csr(L)
    h = mean_kernel(st)
    np.testing.assert_allclose(h, st.weights[:, ::8, ::8].mean(axis=(1, 2)).reshape(5, 5), rtol=1e-6)
    assert mean_kernel(st) is h  # cached
    # the transfer function against NumPy's FFT of the kernel placed circularly around pixel 0
    psf = np.zeros(SHAPE)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            psf[dy % SHAPE[0], dx % SHAPE[1]] = h[dy + 2, dx + 2]
    np.testing.assert_allclose(_transfer(h, SHAPE), np.fft.rfft2(psf), atol=1e-6)


def test_start_inverts_a_spatially_invariant_blur(L):
    """With the same kernel at every pixel, L is a (circular) convolution and the start its inverse."""
    h = mean_kernel(stencil_from_csr(L))
    st = StencilTransport(SHAPE, 2, np.broadcast_to(h.reshape(25, 1, 1), (25, *SHAPE)).astype(np.float32))
    rng = np.random.default_rng(0)
    x = ndi.gaussian_filter(rng.random(SHAPE), 1.0, mode="wrap")
    x = (0.2 + 0.6 * (x - x.min()) / np.ptp(x)).astype(np.float32)  # inside the bounds: nothing clipped
    c = ndi.convolve(x.astype(np.float64), h, mode="wrap").astype(np.float32)  # sum_k h_k x[i - off_k]
    x0 = deconvolved_start(st, c.reshape(-1, 1), lam=1e-9)
    assert x0.shape == (x.size, 1) and x0.dtype == np.float32
    np.testing.assert_allclose(x0[:, 0], x.ravel(), atol=2e-4)


def test_default_start_reaches_the_bounded_optimum_sooner(L):
    c = (0.02 + 0.9 * sample_image(*SHAPE, channels=1, seed=2)).astype(np.float32)
    A = sp.csr_matrix(L, dtype=np.float64)
    ref = lsq_linear(A, c.astype(np.float64).ravel(), bounds=(0, 1), method="trf", tol=1e-12, lsmr_tol=1e-12)
    f_ref = float(np.sum((A @ ref.x - c.ravel()) ** 2))
    op = TransportOperator(L)
    rules = {"tol": 0, "gap_tol": 0, "pg_tol": 0, "max_iter": 300}
    ours = solve(op, c, **rules)
    plain = solve(op, c, x0=np.clip(c, 0, 1), **rules)

    def reach(hist, rel):
        return next(k for k, f in enumerate(hist) if f <= (1 + rel) * f_ref)

    assert reach(ours.history, 0.01) < reach(plain.history, 0.01)
    assert abs(ours.objective - f_ref) <= 1e-3 * f_ref  # the same optimum


def test_video_warm_start_adds_the_deconvolved_change(L):
    """A warm-started frame starts at ``deconvolved(c_new) + x_prev - deconvolved(c_prev)`` (the
    deconvolution's kernel cut at twice the PSF's radius)."""
    wide = (0.02 + 0.9 * sample_image(SHAPE[0], SHAPE[1] + 2, channels=1, seed=4)).astype(np.float32)
    frames = [np.ascontiguousarray(wide[:, k : k + SHAPE[1]]) for k in range(2)]  # a 1 px pan
    op = TransportOperator(L)
    comp = FrameCompensator(op, iterations=3, first_iterations=300)
    first = comp(frames[0])
    again = comp(frames[0])  # the same picture: the start is the previous solution itself
    assert again.history[0] == pytest.approx(first.objective, rel=1e-5)
    ours = comp(frames[1])
    dec = [deconvolved_start(op.stencil, f.reshape(-1, 1), radius=2 * op.stencil.radius).reshape(SHAPE)
           for f in frames]
    start = np.clip(dec[1] + again.x - dec[0], 0, 1)
    assert ours.history[0] == pytest.approx(objective(op, start, frames[1]), rel=1e-5)
    # the plain change of the target (as on CSR) is the worse start with the same budget
    plain = solve(op, frames[1], x0=frames[1] + again.x - frames[0], max_iter=3, gap_tol=0, pg_tol=0)
    assert ours.objective < plain.objective


def test_the_cut_kernel_deconvolves_as_the_ffts_do_away_from_the_edges():
    """The Wiener filter applied in the image domain with its kernel cut (the video's warm start)
    agrees with the FFTs inside the image; the blur is lopsided, so a kernel not mirrored for
    filter2D's correlation would not."""
    shape = (48, 64)
    h = np.zeros((5, 5))
    h[2, 2], h[2, 3], h[1, 2], h[2, 4] = 0.45, 0.3, 0.15, 0.1   # light thrown right and up
    st = StencilTransport(shape, 2, np.broadcast_to(h.reshape(25, 1, 1), (25, *shape)).astype(np.float32))
    rng = np.random.default_rng(3)
    x = ndi.gaussian_filter(rng.random(shape), 1.5, mode="wrap")
    c = ndi.convolve(0.3 + 0.4 * (x - x.min()) / np.ptp(x), h, mode="wrap").astype(np.float32).reshape(-1, 1)
    ffts = deconvolved_start(st, c, lam=1e-2).reshape(shape)
    cut = deconvolved_start(st, c, lam=1e-2, radius=10).reshape(shape)
    inner = (slice(12, -12), slice(12, -12))
    np.testing.assert_allclose(cut[inner], ffts[inner], atol=2e-3)
    # mirrored back, the kernel undoes the blur: convolved with h it is nearly a point (the ridge
    # keeps it from being one); unmirrored it would spread the point over half a dozen pixels
    k = wiener_kernel(st, 10, lam=1e-2)
    assert k.shape == (21, 21) and k.dtype == np.float32
    e = ndi.convolve(np.pad(k[::-1, ::-1].astype(np.float64), 4), h, mode="constant")
    centre = (e.shape[0] // 2, e.shape[1] // 2)
    assert e[centre] > 0.85
    e[centre] = 0
    assert np.abs(e).max() < 0.06
    with pytest.raises(ValueError, match="radius"):
        wiener_kernel(st, 0)
