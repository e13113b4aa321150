"""The constant-capture calibration mode on a mesh: every projector at once, lifted to 3D.

The planar multiplexed mode (:mod:`imaging.calibration.multiplex`) measures, with a
number of captures that does not depend on the number of projectors, where projector
pixels land in the camera. On a table a homography turns camera pixels into table points;
on an object the camera's rays are cast onto the surface instead
(:class:`imaging.calibration.threed.SurfaceCaster`: a world point per camera pixel),
which gives world point <-> projector pixel correspondences for every projector from the
same captures, and the sequential mode's pose solve (normalised DLT, then
``cv2.calibrateCamera``; :func:`imaging.calibration.threed.calibrate_projector`) gives
each projector's 3x4 pose. The stage that runs it is
:mod:`coordinator.calibration.stages.dots3d`:

1. **Coded dots** (``2 bits`` captures, as on the table): every projector's coded dots are
   decoded in every posed camera, each dot's sub-pixel camera centroid is lifted onto the
   surface (:func:`lift`) and a coarse pose is fitted through them (:func:`fit_pose`).
2. **Surface lattice** (``rounds`` captures): sites on the surface the camera sees (the
   object and the table around it) are shared out between the projectors that light them,
   and each projector draws a dot where its pose so far puts its sites
   (:func:`imaging.calibration.alignment.plan_surface_lattice`, the alignment check's
   pattern), so no two dots overlap on the object; one capture measures every projector's
   dots. Half the rounds are planned through the coarse poses with 3-pixel dots (a lattice
   step tolerates a coarse pose a few pixels off), the other half through the poses those
   dots gave, with single-pixel dots on a denser lattice. The lifted centroids of both give
   the final pose.

Why coarse poses need care: a projector's image spans the whole table and the object
covers a tenth of it, so of its few dozen coded dots only one or two may land on the
object. Points on one plane fix only a homography (the DLT is then degenerate, or at the
mercy of noise), so :func:`fit_pose` fixes the principal point at the image centre and
square pixels unless the points leave their plane; the lattice's dots on the object then
free every intrinsic (a lens-shifted projector's principal point is far from the centre).

:func:`lift` intersects the ray through a sub-pixel position with the plane through the
four cast points around it: exactly on the ray, exact on the table and wherever the four
lie on one facet, and within a tenth of a pixel's footprint elsewhere on a mesh (a
brute-force ray/triangle intersection is its test's reference).
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy.optimize import least_squares

from imaging.calibration.errors import CalibrationError
from imaging.calibration.threed import DeviceFit, Pinhole, calibrate_projector, project, residuals

__all__ = ["lift", "rays", "off_plane", "fit_pose", "MIN_OFF_PLANE"]

#: Fewest correspondences off the plane that holds most of them for a free pinhole (else the principal
#: point is fixed at the image centre).
MIN_OFF_PLANE = 8


def rays(camera: Pinhole, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rays through camera pixel positions.

    Parameters
    ----------
    camera : Pinhole
    xy : (M, 2) float64 camera pixels (pixel centres at integers)

    Returns
    -------
    origin : (3,) float64 the camera centre, world mm
    directions : (M, 3) float64 unit world directions
    """
    xy = np.asarray(xy, np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must be (M, 2), got {xy.shape}")
    h = np.column_stack([xy, np.ones(len(xy))])
    d = np.linalg.solve(camera.K, h.T).T @ camera.R       # R^T K^-1 x, row-wise
    return camera.center, d / np.linalg.norm(d, axis=1, keepdims=True)


def lift(camera: Pinhole, points: np.ndarray, usable: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The surface points seen at sub-pixel camera positions.

    The ray through each position is intersected with the plane through the
    four cast points around it (the pixel centres ``floor(x), floor(x) + 1`` by
    ``floor(y), floor(y) + 1``; plane normal the cross product of the quad's
    diagonals). A position whose four neighbours are not all ``usable``, whose
    quad is degenerate, or whose intersection falls farther from the quad's
    centre than its longer diagonal, gets NaN.

    Parameters
    ----------
    camera : Pinhole
        The camera the points were cast from.
    points : (H, W, 3) float64
        World mm seen at each camera pixel centre (:meth:`SurfaceCaster.cast`; NaN where nothing).
    usable : (H, W) bool
        Pixels whose points may be used (on the surface, away from silhouettes and depth steps).
    xy : (M, 2) float64
        Camera positions, pixel centres at integer coordinates.

    Returns
    -------
    (M, 3) float64 world mm; NaN rows where the position cannot be lifted.
    """
    points = np.asarray(points, np.float64)
    usable = np.asarray(usable, bool)
    if points.ndim != 3 or points.shape[2] != 3 or usable.shape != points.shape[:2]:
        raise ValueError(f"need points (H, W, 3) and usable (H, W), got {points.shape}, {usable.shape}")
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    H, W = usable.shape
    out = np.full((len(xy), 3), np.nan)
    fin = np.isfinite(xy).all(axis=1)
    x0 = np.floor(np.where(fin, xy[:, 0], -1)).astype(np.int64)
    y0 = np.floor(np.where(fin, xy[:, 1], -1)).astype(np.int64)
    ok = fin & (x0 >= 0) & (y0 >= 0) & (x0 < W - 1) & (y0 < H - 1)
    x0, y0 = np.where(ok, x0, 0), np.where(ok, y0, 0)
    for dy in (0, 1):
        for dx in (0, 1):
            ok &= usable[y0 + dy, x0 + dx]
    if not ok.any():
        return out
    x0, y0 = x0[ok], y0[ok]
    p00, p10 = points[y0, x0], points[y0, x0 + 1]
    p01, p11 = points[y0 + 1, x0], points[y0 + 1, x0 + 1]
    d1, d2 = p11 - p00, p10 - p01
    normal = np.cross(d1, d2)
    centre = (p00 + p10 + p01 + p11) / 4.0
    span = np.maximum(np.linalg.norm(d1, axis=1), np.linalg.norm(d2, axis=1))
    origin, d = rays(camera, xy[ok])
    denom = np.einsum("ij,ij->i", normal, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.einsum("ij,ij->i", normal, centre - origin) / denom
    X = origin + s[:, None] * d
    good = (np.isfinite(X).all(axis=1) & (s > 0) & (np.linalg.norm(normal, axis=1) > 1e-12 * span ** 2)
            & (np.linalg.norm(X - centre, axis=1) <= span))
    X[~good] = np.nan
    out[np.flatnonzero(ok)] = X
    return out


def off_plane(X: np.ndarray, *, tolerance_mm: float = 10.0, trials: int = 200, seed: int = 0) -> int:
    """How many of the points (N, 3) lie farther than ``tolerance_mm`` from the plane that holds most of them.

    The plane is the best of ``trials`` planes through three of the points (RANSAC):
    a least-squares plane would tilt towards the few points on an object and count
    the table's as off it.
    """
    X = np.asarray(X, np.float64).reshape(-1, 3)
    n = len(X)
    if n < 4:
        return 0
    rng = np.random.default_rng(seed)
    tri = rng.integers(0, n, (trials, 3))
    normal = np.cross(X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]])
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return 0
    normal = normal[ok] / norm[ok, None]
    dist = np.abs((X[None, :, :] - X[tri[ok, 0]][:, None, :]) @ normal[:, :, None])[..., 0]   # (trials, N)
    return int(n - (dist <= tolerance_mm).sum(axis=1).max())


def _pnp(X: np.ndarray, x: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> Pinhole | None:
    try:
        # SQPnP: a global solution for any layout (the iterative method's DLT start fails on
        # a plane with a point or two off it, which is what a projector's coded dots often are)
        ok, rvec, tvec = cv2.solvePnP(X, x, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if ok:
            rvec, tvec = cv2.solvePnPRefineLM(X, x, K, None, rvec, tvec)
    except cv2.error:
        return None
    if not ok:
        return None
    return Pinhole(K, cv2.Rodrigues(rvec)[0], tvec.reshape(3), size)


def _fixed_centre(X: np.ndarray, x: np.ndarray, size: tuple[int, int], threshold: float, rounds: int) -> DeviceFit:
    """Focal length and pose with the principal point at the image centre and square pixels.

    A plane seen nearly face-on hardly fixes the focal length (Zhang's single-view
    estimate is then noise), so the start is the best of focal lengths from a quarter to
    eight times the image's width (``cv2.solvePnP`` for each, scored by the median
    residual); a least-squares fit of the focal length and the pose
    (``scipy.optimize.least_squares``) then refines it, trimming points beyond
    ``threshold`` px.
    """
    w, h = size

    def K_of(f: float) -> np.ndarray:
        return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])

    best, best_score = None, np.inf
    for f in np.geomspace(0.25, 8.0, 25) * max(w, h):
        dev = _pnp(X, x, K_of(float(f)), size)
        if dev is None:
            continue
        score = float(np.median(residuals(dev, X, x)))
        if score < best_score:
            best, best_score = dev, score
    if best is None:
        raise CalibrationError("no projection agrees with the correspondences")

    def unpack(p: np.ndarray) -> Pinhole:
        return Pinhole(K_of(float(p[0])), cv2.Rodrigues(p[1:4])[0], p[4:7], size)

    def resid(p: np.ndarray, A: np.ndarray, a: np.ndarray) -> np.ndarray:
        px, _ = project(unpack(p).P, A)
        return (px - a).ravel()

    dev = best
    for _ in range(max(1, rounds)):
        r = residuals(dev, X, x)
        use = r <= max(threshold, 3.0 * float(np.median(r)))
        if use.sum() < 6:
            break
        p0 = np.concatenate([[dev.K[0, 0]], cv2.Rodrigues(dev.R)[0].ravel(), dev.t])
        sol = least_squares(resid, p0, args=(X[use], x[use]), x_scale="jac")
        if not (np.all(np.isfinite(sol.x)) and sol.x[0] > 0):
            break
        dev = unpack(sol.x)
    inl = residuals(dev, X, x) <= threshold
    if inl.sum() < 6:
        raise CalibrationError(f"only {int(inl.sum())} correspondences agree with one projection")
    r = residuals(dev, X[inl], x[inl])
    return DeviceFit(dev, float(np.sqrt(np.mean(r ** 2))), float(r.max()), int(inl.sum()), inl)


def fit_pose(X: np.ndarray, x: np.ndarray, size: tuple[int, int], *, threshold: float = 2.0, seed: int = 0,
             rounds: int = 3) -> tuple[DeviceFit, bool]:
    """A projector's pinhole from world <-> projector pixel correspondences, also when they are nearly coplanar.

    With at least :data:`MIN_OFF_PLANE` points off the plane holding most of them
    (:func:`off_plane`: an object standing on the table), the sequential mode's solve
    (:func:`imaging.calibration.threed.calibrate_projector`: DLT, then
    ``cv2.calibrateCamera`` with every intrinsic free but skew and distortion). With
    fewer (a projector whose coded dots mostly landed on the table), a plane fixes only a
    homography, and the principal point is then fixed at the image centre with square
    pixels: a coarse pose for planning where the next dots go, which the lattice's dots
    on the object then free.

    Parameters
    ----------
    X : (N, 3) float64 world mm
    x : (N, 2) float64 projector pixels
    size : (w, h) of the projector

    Returns
    -------
    (DeviceFit, free): ``free`` tells whether every intrinsic was fitted.
    """
    X = np.asarray(X, np.float64)
    x = np.asarray(x, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (len(X), 2):
        raise ValueError(f"need X (N, 3) and x (N, 2), got {X.shape}, {x.shape}")
    if off_plane(X) >= MIN_OFF_PLANE:
        return calibrate_projector(X, x, size, threshold=threshold, seed=seed, rounds=rounds), True
    if len(X) < 6:
        raise CalibrationError(f"need at least 6 correspondences to pose a projector, got {len(X)}")
    return _fixed_centre(X, x, size, threshold, rounds), False
