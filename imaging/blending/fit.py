"""Each projector's contribution from its blob samples: a smooth model in its own pixels.

**White.** A projector's light at full white, seen on a planar surface, is smooth in its own
pixels: lens fall-off and vignetting toward the corners, a hot spot, the distance and angle to
the surface, its brightness and white point. Per channel, ``log T_c(u)`` is modelled in the
projector's normalised coordinates. First a polynomial of total degree ``degree`` (4: 15 terms;
lowered when a projector has fewer than three samples per term) is fitted by least squares with
reweighting rounds that drop samples more than 4 MADs off (a hand, a speck). Then the inliers are
interpolated with a smoothing thin-plate spline (a hot spot is narrower than a low-degree
polynomial follows: on the synthetic rigs of the tests the spline's error is half the
polynomial's); ``smoothing`` trades the camera's noise against detail. The model is evaluated at
every grid point inside the projector's frame and on the surface, clamped to a little beyond the
range its samples span (a model is not trusted far beyond them), and 0 elsewhere.

**Black.** One black capture measures the rig's total black. Assumed: every projector's black is
the same fraction of its white, per channel (the same contrast ratio for units of one model), so
``black_i = k_c T_ic`` with ``k_c`` the median of ``black_c / sum_i T_ic`` over the well-lit
surface. A unit whose black is brighter than its peers' makes the beta floor a little uneven
where it reaches; measure it alone to see (`shadowless response` reports each black).
"""
from __future__ import annotations

import math
from typing import Mapping

import cv2
import numpy as np
from scipy.interpolate import RBFInterpolator

from imaging.blending.contributions import Contributions, grid_shape, grid_to_camera, luma, projector_mapper
from imaging.blending.errors import BlendError
from imaging.blending.sample_plan import SamplePlan
from imaging.blending.samples import Samples

__all__ = ["fit_contributions", "poly_basis", "MIN_SAMPLES"]

#: fewer samples than this and a projector's light cannot be modelled
MIN_SAMPLES = 6


def poly_basis(a: np.ndarray, b: np.ndarray, degree: int) -> np.ndarray:
    """``(n, terms)`` monomials ``a^p b^q``, ``p + q <= degree``, of normalised coordinates."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    pa, pb = [np.ones_like(a)], [np.ones_like(b)]
    for _ in range(degree):
        pa.append(pa[-1] * a)
        pb.append(pb[-1] * b)
    return np.stack([pa[p] * pb[d - p] for d in range(degree + 1) for p in range(d, -1, -1)], axis=-1)


def _terms(degree: int) -> int:
    return (degree + 1) * (degree + 2) // 2


def _normalised(u: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    W, H = size
    return (u[..., 0] + 0.5) / W * 2.0 - 1.0, (u[..., 1] + 0.5) / H * 2.0 - 1.0


def _grid_at(grid: np.ndarray, points: np.ndarray, camera_size: tuple[int, int]) -> np.ndarray:
    """``grid`` ((h, w) over the camera image) at camera pixels ``points`` ((n, 2)), bilinear, 0 outside."""
    W, H = camera_size
    h, w = grid.shape
    gx = ((points[:, 0] + 0.5) * (w / W) - 0.5).astype(np.float32)[None, :]
    gy = ((points[:, 1] + 0.5) * (h / H) - 0.5).astype(np.float32)[None, :]
    return cv2.remap(np.nan_to_num(grid).astype(np.float32), gx, gy, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)[0].astype(np.float64)


def _fit_log(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robust least squares of ``A x = y`` (y: (n, 3)); returns x (terms, 3) and the inlier mask."""
    keep = np.ones(len(y), bool)
    x = None
    for _ in range(3):
        x, *_ = np.linalg.lstsq(A[keep], y[keep], rcond=None)
        res = np.abs(A @ x - y).max(axis=1)
        mad = float(np.median(res[keep])) * 1.4826 + 1e-4
        new = res <= 4.0 * mad
        if new.sum() < A.shape[1] or np.array_equal(new, keep):
            break
        keep = new
    return x, keep


def fit_contributions(plan: SamplePlan, samples: Samples, black: np.ndarray, camera_to_projector: Mapping[str, np.ndarray],
                      *, scale: int, surface: np.ndarray | None = None, degree: int = 4,
                      smoothing: float | None = None, shading: Mapping[str, np.ndarray] | None = None,
                      shaded: bool = False) -> tuple[Contributions, dict]:
    """The rig's :class:`Contributions` from the blob samples and the black capture.

    Parameters
    ----------
    plan : SamplePlan
    samples : Samples
    black : (H, W, 3) float32
        The black capture (every projector black), full camera resolution.
    scale : int
        Grid = camera / scale.
    surface : (h, w) bool, optional
        The surface on the grid (default: everywhere).
    degree : int
        The screening polynomial's total degree (lowered for a projector with few samples).
    smoothing : float
        The thin-plate spline's smoothing (0: it passes through every inlier; None: the polynomial alone).
    shading : slot -> (h, w) float, optional
        A known factor of each projector's light on the grid (a mesh: the cosine of the light's incidence
        over the squared distance, which changes with the surface's shape, not smoothly in the projector's
        pixels); the smooth model is fitted to the light divided by it and multiplied back.
    shaded : bool
        The samples already have the shading divided out (:func:`imaging.blending.mesh_samples.read_capture_shaded`).
    camera_to_projector : slot -> (3, 3) float64 or (h', w', 2)
        Full-camera pixels -> projector pixels (those the plan placed the blobs with): a homography, or a mesh
        rig's projector coordinates on a grid over the camera image (the result then holds them on its grid).

    Returns
    -------
    Contributions, and per slot its figures (samples, inliers, degree, rms log residual).
    """
    Hc, Wc = black.shape[:2]
    shape = grid_shape((Wc, Hc), scale)
    pts = grid_to_camera((Wc, Hc), shape)
    surf = np.ones(shape, bool) if surface is None else np.asarray(surface, bool)
    if surf.shape != shape:
        raise ValueError(f"surface must be {shape} (the grid), got {surf.shape}")
    mats = {s: np.asarray(camera_to_projector[s]) for s in plan.slots}
    mesh = {s for s in plan.slots if mats[s].shape != (3, 3)}
    xy: dict[str, np.ndarray] = {}
    white: dict[str, np.ndarray] = {}
    figures: dict[str, dict] = {}
    for s in plan.slots:
        M = mats[s]
        size = plan.projector_size[s]
        sites, values = samples.arrays(s)
        shade = None
        if shading is not None and s in shading:
            shade = np.asarray(shading[s], np.float32)
            if not shaded:
                at = _grid_at(shade, plan.sites[sites], (Wc, Hc))
                values = np.where((at > 0)[:, None], values / np.maximum(at, 1e-12)[:, None], 0.0)
        lum = luma(values.astype(np.float32))
        ok = np.all(values > 0, axis=1)
        if ok.sum() >= MIN_SAMPLES:
            ok &= lum > 0.05 * float(np.median(lum[ok]))
        n = int(ok.sum())
        if n < MIN_SAMPLES:
            raise BlendError(f"projector {s}: only {n} usable blob samples (at least {MIN_SAMPLES} needed): is it "
                             "powered, and does the camera see its light? (try a smaller --blob-spacing)")
        deg = int(degree)
        while deg > 0 and n < 3 * _terms(deg):
            deg -= 1
        a, b = _normalised(plan.projector_xy[s][sites[ok]], size)
        y = np.log(values[ok])
        x, inl = _fit_log(poly_basis(a, b, deg), y)
        u = projector_mapper(M, (Wc, Hc))(pts)
        if s in mesh:
            xy[s] = u.astype(np.float32)
        ga, gb = _normalised(u, size)
        inside = np.isfinite(ga) & np.isfinite(gb) & (np.abs(ga) <= 1.0) & (np.abs(gb) <= 1.0) & surf
        logt = np.zeros((*shape, 3))
        spline = None
        if smoothing is not None and inl.sum() >= 10:
            spline = RBFInterpolator(np.stack([a[inl], b[inl]], axis=-1), y[inl], kernel="thin_plate_spline",
                                     smoothing=float(smoothing) * int(inl.sum()), degree=1)
        if inside.any():
            pts_in = np.stack([ga[inside], gb[inside]], axis=-1)
            vals = spline(pts_in) if spline is not None else poly_basis(ga[inside], gb[inside], deg) @ x
            lo, hi = y[inl].min(axis=0) - 0.5, y[inl].max(axis=0) + 0.2
            logt[inside] = np.clip(vals, lo, hi)
        light = np.exp(logt) if shade is None else np.exp(logt) * np.nan_to_num(shade)[..., None]
        if shade is not None:
            inside &= np.nan_to_num(shade) > 0
        white[s] = np.where(inside[..., None], light, 0.0).astype(np.float32)
        rms = float(np.sqrt(np.mean((poly_basis(a, b, deg)[inl] @ x - y[inl]) ** 2))) if inl.any() else math.nan
        figures[s] = {"samples": n, "inliers": int(inl.sum()), "degree": deg, "rms_log": round(rms, 5),
                      "spline": spline is not None}
    total = sum(white.values())
    bgrid = cv2.resize(np.asarray(black, np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    lit = surf & (luma(total) > 0.2 * float(luma(total).max()))
    k = np.zeros(3)
    if lit.any():
        k = np.maximum(np.median(bgrid[lit] / np.maximum(total[lit], 1e-9), axis=0), 0.0)
    ks = _black_shares(white, bgrid, lit, k, plan.slots)
    blk = {s: (white[s] * ks[s][None, None, :].astype(np.float32)).astype(np.float32) for s in plan.slots}
    sizes = {s: plan.projector_size[s] for s in plan.slots}
    homographies = {s: np.eye(3) if s in mesh else mats[s].astype(np.float64) for s in plan.slots}
    contributions = Contributions((Wc, Hc), scale, white, blk, homographies, sizes, xy or None)
    for s in plan.slots:
        figures[s]["black_fraction"] = [round(float(v), 6) for v in ks[s]]
    return contributions, {"slots": figures, "black_fraction": [round(float(v), 6) for v in k]}


def _black_shares(white: Mapping[str, np.ndarray], black: np.ndarray, lit: np.ndarray, common: np.ndarray,
                  slots: list[str], *, prior: float = 0.01) -> dict[str, np.ndarray]:
    """Each projector's black as a fraction of its white, per channel: the least-squares split of the
    measured black ``sum_i k_i T_i`` over the lit surface, pulled toward the ``common`` fraction with a weight
    of ``prior`` of the data's (units of one model differ in contrast: where footprints differ, as on a
    wall, the data tell them apart; where every projector covers the same area they cannot, and the
    common fraction stands). Never negative."""
    n = len(slots)
    if n == 0 or not lit.any():
        return {s: common.copy() for s in slots}
    A = np.stack([white[s][lit] for s in slots], axis=1).astype(np.float64)   # (m, n, 3)
    b = black[lit].astype(np.float64)                                        # (m, 3)
    out = np.zeros((n, 3))
    for c in range(3):
        M = A[:, :, c]
        G = M.T @ M
        lam = prior * float(np.trace(G)) / n
        rhs = M.T @ b[:, c] + lam * common[c]
        try:
            out[:, c] = np.linalg.solve(G + lam * np.eye(n), rhs)
        except np.linalg.LinAlgError:
            out[:, c] = common[c]
    out = np.maximum(out, 0.0)
    return {s: out[i] for i, s in enumerate(slots)}

