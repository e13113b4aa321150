"""Pinhole cameras and projectors in the world frame (millimetres).

Conventions (OpenCV): a world point ``X`` maps to the device frame as
``Xc = R @ X + t``; the device looks along its +z axis (positive depth in
front), x to the right, y down; pixel ``(x, y)`` has its centre at integer
``(x, y)``. ``P = K @ [R | t]`` maps homogeneous world points to pixels.

The world frame: table plane z = 0, z up, ceiling above.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# defined beside the other conventions every process shares (the coordinator reads layouts too)
from protos.spaces import intrinsics, look_at, scale_intrinsics  # noqa: F401


def _as_points(points: np.ndarray, *, name: str = "points") -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim < 1 or pts.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {pts.shape}")
    return pts


def rotation_about(axis, angle_rad: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``angle_rad`` about ``axis`` (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * (k @ k)


def projection_matrix(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``P = K [R | t]``: (3, 4) float64."""
    return np.asarray(K, np.float64) @ np.hstack([np.asarray(R, np.float64), np.asarray(t, np.float64).reshape(3, 1)])


def project(P: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points through a (3, 4) matrix.

    Parameters
    ----------
    P : (3, 4) float64
    points : (..., 3) float64
        World millimetres.

    Returns
    -------
    pixels : (..., 2) float64
    w : (...,) float64
        Third homogeneous coordinate: the depth along the optical axis when
        ``P = K [R | t]`` with K's last row (0, 0, 1).
    """
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (3, 4):
        raise ValueError(f"P must be (3, 4), got {P.shape}")
    pts = _as_points(points)
    h = pts @ P[:, :3].T + P[:, 3]
    w = h[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = h[..., :2] / w[..., None]
    return pix, w


def plane_homography(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homography from the table plane (x, y mm at z = 0) to the device's pixels.

    Returns
    -------
    H : (3, 3) float64, ``H = K [r1 r2 t]`` normalised so ``H[2, 2] = 1``.
    """
    R = np.asarray(R, np.float64)
    H = np.asarray(K, np.float64) @ np.column_stack([R[:, 0], R[:, 1], np.asarray(t, np.float64).reshape(3)])
    return H / H[2, 2]


def intersect_plane_z(origins: np.ndarray, directions: np.ndarray, *, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Intersect rays with the horizontal plane at height ``z``.

    Returns
    -------
    points : (..., 3) float64
    distance : (...,) float64
        Ray parameter (the distance when ``directions`` are unit); ``inf``
        where the ray is parallel to the plane or the plane is behind.
    """
    o = _as_points(origins, name="origins")
    d = _as_points(directions, name="directions")
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z - o[..., 2]) / d[..., 2]
    s = np.where(np.isfinite(s) & (s > 0), s, np.inf)
    pts = o + np.where(np.isfinite(s), s, 0.0)[..., None] * d
    return pts, s


@dataclass(frozen=True, eq=False)
class Pinhole:
    """A pinhole device (camera or projector) at one resolution.

    Attributes
    ----------
    K : (3, 3) float64
    R : (3, 3) float64
    t : (3,) float64
    size : (int, int)
        (width, height) in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]
    _P: np.ndarray = field(init=False, repr=False)
    _center: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        R = np.asarray(self.R, dtype=np.float64)
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        if K.shape != (3, 3) or R.shape != (3, 3) or t.shape != (3,):
            raise ValueError(f"K, R, t must be (3, 3), (3, 3), (3,); got {K.shape}, {R.shape}, {t.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("R must be a proper rotation")
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise ValueError(f"size must be positive, got {self.size}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "size", (w, h))
        object.__setattr__(self, "_P", projection_matrix(K, R, t))
        object.__setattr__(self, "_center", -R.T @ t)

    @property
    def P(self) -> np.ndarray:
        """(3, 4) float64 world mm -> pixels."""
        return self._P.copy()

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 optical centre in world mm."""
        return self._center.copy()

    @property
    def axis(self) -> np.ndarray:
        """(3,) float64 unit viewing direction in the world."""
        return self.R[2].copy()

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``(..., 2)`` and depths ``(...,)`` of world points ``(..., 3)``."""
        return project(self._P, points)

    def to_device(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` in the device frame ``(..., 3)``."""
        return _as_points(points) @ self.R.T + self.t

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit world directions ``(..., 3)`` through pixels ``(..., 2)``."""
        pix = np.asarray(pixels, dtype=np.float64)
        if pix.shape[-1] != 2:
            raise ValueError(f"pixels must be (..., 2), got {pix.shape}")
        homog = np.concatenate([pix, np.ones(pix.shape[:-1] + (1,))], axis=-1)
        d = homog @ np.linalg.inv(self.K).T @ self.R  # (R^T K^-1 x)^T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pixel_grid(self, roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Pixel centres ``(h, w, 2)`` float64 of the image or of ``roi`` = (x0, y0, x1, y1)."""
        x0, y0, x1, y1 = (0, 0, *self.size) if roi is None else roi
        xs, ys = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
        return np.stack([xs, ys], axis=-1)

    def table_homography(self) -> np.ndarray:
        """(3, 3) float64: table mm (x, y, z = 0) -> pixels."""
        return plane_homography(self.K, self.R, self.t)

    def scaled(self, size: tuple[int, int]) -> "Pinhole":
        """The same optics sampled at another resolution."""
        return Pinhole(scale_intrinsics(self.K, self.size, size), self.R, self.t, size)

    def gl_projection(self, *, near: float, far: float) -> np.ndarray:
        """(4, 4) float64 world -> OpenGL clip coordinates for this device.

        Window row 0 is image row 0 (y is not flipped), so a framebuffer read
        back row by row is already in OpenCV order. Pixel centres match: a
        fragment at window (x + 0.5, y + 0.5) is pixel (x, y).
        """
        if not 0 < near < far:
            raise ValueError("need 0 < near < far")
        w, h = self.size
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        M = np.array(
            [
                [2 * fx / w, 2 * s / w, (2 * cx + 1) / w - 1, 0.0],
                [0.0, 2 * fy / h, (2 * cy + 1) / h - 1, 0.0],
                [0.0, 0.0, (far + near) / (far - near), -2 * far * near / (far - near)],
                [0.0, 0.0, 1.0, 0.0],
            ]
        )
        V = np.eye(4)
        V[:3, :3] = self.R
        V[:3, 3] = self.t
        return M @ V


def pixel_footprint_area(device: Pinhole, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Area (mm^2) of one pixel's footprint on a surface, for each point.

    A pixel subtends the solid angle ``cos^3(a) / (fx fy)`` at off-axis angle
    ``a``; at distance ``d`` on a surface tilted by ``theta`` from the ray it
    covers ``d^2 omega / cos(theta)``.

    Parameters
    ----------
    points, normals : (..., 3) float64
        Surface points (world mm) and unit normals.

    Returns
    -------
    area : (...,) float64; ``inf`` where the surface is seen edge-on or from behind.
    """
    pts = _as_points(points)
    nrm = _as_points(normals, name="normals")
    v = device.center - pts
    d = np.linalg.norm(v, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_theta = np.einsum("...i,...i->...", nrm, v) / d
        cos_a = ((pts - device.center) @ device.axis) / d
        omega = cos_a**3 / (device.K[0, 0] * device.K[1, 1])
        area = d * d * omega / cos_theta
    return np.where((cos_theta > 1e-9) & (cos_a > 0), area, np.inf)
