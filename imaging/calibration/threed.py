"""3D calibration numerics: meshes, cameras posed to the world, mesh registration,
camera rays cast onto the surface, and each projector's intrinsics and pose.

Pipeline (sequential Gray codes, like the paper, but with thousands of
correspondences per projector instead of its 20 landmarks):

1. Cameras are posed in the world (``K``, ``R``, ``t``; OpenCV pinhole, no
   distortion) from known points: table points (z = 0) and/or mesh landmarks
   given in world coordinates (:func:`pose_camera`).
2. A mesh given in its own (model) coordinates is registered to the world from
   landmarks (model points <-> camera pixels) seen by the posed cameras
   (:func:`register_mesh`).
3. Every camera pixel's ray is cast onto the surface (the mesh, and the table
   plane when there is one) by rasterising it with OpenGL
   (:class:`SurfaceCaster`): a world point per camera pixel.
4. Decoded Gray codes give the projector pixel each camera pixel sees, hence
   world point <-> projector pixel correspondences by the thousand; a
   normalised DLT gives the initial guess and ``cv2.calibrateCamera`` with
   ``CALIB_USE_INTRINSIC_GUESS`` (pinhole, zero distortion: a node renders with a
   3x4 matrix) refines the projector's ``K``, ``R``, ``t`` (:func:`calibrate_projector`).

Meshes follow the project's convention: vertices (V, 3) float32 mm, faces
(F, 3) uint32, uvs (V, 2) float32 in [0, 1] with (0, 0) the content image's
top-left corner. OBJ and PLY store texture v growing upwards; reading flips it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares

from imaging.calibration.errors import CalibrationError
from imaging.calibration.planar import fit_homography
from imaging.calibration.points import PointSet
from protos.mesh_files import MeshFileError, read_mesh
from imaging.egl import standalone_context

SHADERS = Path(__file__).resolve().parent / "shaders"
TABLE, MESH = 1, 2

#: A camera posed from table points alone (unknown intrinsics) must view the table at least this obliquely.
MIN_TILT_DEG = 25.0


# ---------------------------------------------------------------------- meshes
@dataclass(frozen=True, eq=False)
class MeshData:
    """vertices (V, 3) float32 mm, faces (F, 3) uint32, uvs (V, 2) float32 or None."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices, np.float32)
        f = np.ascontiguousarray(self.faces, np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"mesh must have vertices (V, 3) and faces (F, 3), got {v.shape}, {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise CalibrationError(f"mesh faces reference vertex {int(f.max())} but there are {len(v)} vertices")
        if not np.all(np.isfinite(v)):
            raise CalibrationError("mesh vertices contain NaN or infinite coordinates")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f.astype(np.uint32))
        if self.uvs is not None:
            uv = np.ascontiguousarray(self.uvs, np.float32)
            if uv.shape != (len(v), 2):
                raise ValueError(f"uvs must be (V, 2), got {uv.shape}")
            object.__setattr__(self, "uvs", uv)

    def transformed(self, R: np.ndarray, t: np.ndarray) -> "MeshData":
        """``x -> R x + t`` (model -> world)."""
        v = self.vertices.astype(np.float64) @ np.asarray(R, np.float64).T + np.asarray(t, np.float64).reshape(3)
        return MeshData(v, self.faces, self.uvs)


def load_mesh(path: str | Path) -> MeshData:
    """Read a triangle mesh from ``.obj`` or ``.ply`` (ASCII or binary) through
    :mod:`protos.mesh_files`: polygons become fans, texture coordinates are kept when every
    vertex has one (an OBJ vertex used with several texture coordinates is split)."""
    try:
        m = read_mesh(path)
    except MeshFileError as exc:
        raise CalibrationError(str(exc)) from None
    return MeshData(m.vertices, m.faces, m.uvs)


# ---------------------------------------------------------------------- pinhole devices
@dataclass(frozen=True, eq=False)
class Pinhole:
    """A posed pinhole device: ``x ~ K (R X + t)``, pixel centres at integers, positive depth in front.

    Attributes
    ----------
    K, R : (3, 3) float64
    t : (3,) float64
    size : (w, h)
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]

    def __post_init__(self):
        for name, shape in (("K", (3, 3)), ("R", (3, 3))):
            a = np.asarray(getattr(self, name), np.float64)
            if a.shape != shape:
                raise ValueError(f"{name} must be {shape}, got {a.shape}")
            object.__setattr__(self, name, a)
        t = np.asarray(self.t, np.float64).reshape(-1)
        if t.shape != (3,):
            raise ValueError(f"t must be (3,), got {t.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))

    @property
    def P(self) -> np.ndarray:
        """(3, 4) float64 world mm -> pixels."""
        return self.K @ np.column_stack([self.R, self.t])

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths (N,) of world points (N, 3)."""
        return project(self.P, X)

    def to_dict(self) -> dict:
        return {"K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(), "size": list(self.size)}

    @classmethod
    def from_dict(cls, doc: dict) -> "Pinhole":
        return cls(np.array(doc["K"]), np.array(doc["R"]), np.array(doc["t"]), tuple(doc["size"]))


def project(P: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (N, 3) through a (3, 4) matrix: pixels (N, 2) float64 and depths (N,) float64."""
    X = np.asarray(X, np.float64).reshape(-1, 3)
    h = X @ np.asarray(P, np.float64)[:, :3].T + np.asarray(P, np.float64)[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[:, :2] / h[:, 2:3], h[:, 2]


def _hartley(x: np.ndarray) -> np.ndarray:
    """Similarity that moves points to their centroid with mean distance sqrt(dim)."""
    d = x.shape[1]
    c = x.mean(axis=0)
    s = math.sqrt(d) / max(float(np.mean(np.linalg.norm(x - c, axis=1))), 1e-12)
    T = np.eye(d + 1)
    T[:d, :d] *= s
    T[:d, d] = -s * c
    return T


def dlt(X: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Normalised direct linear transform: the (3, 4) P with ``x ~ P X`` (least squares, algebraic).

    Parameters
    ----------
    X : (N, 3) float64 world points, not all coplanar, N >= 6
    x : (N, 2) float64 pixels

    Returns
    -------
    P : (3, 4) float64, scaled so points in front have positive depth
    """
    X = np.asarray(X, np.float64)
    x = np.asarray(x, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (len(X), 2):
        raise ValueError(f"need X (N, 3) and x (N, 2), got {X.shape}, {x.shape}")
    if len(X) < 6:
        raise CalibrationError(f"need at least 6 points for a projection matrix, got {len(X)}")
    T3, T2 = _hartley(X), _hartley(x)
    Xn = np.column_stack([X, np.ones(len(X))]) @ T3.T
    xn = np.column_stack([x, np.ones(len(x))]) @ T2.T
    n = len(X)
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xn
    A[0::2, 8:12] = -xn[:, 0:1] * Xn
    A[1::2, 4:8] = Xn
    A[1::2, 8:12] = -xn[:, 1:2] * Xn
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    if s[-2] < 1e-12 * s[0]:
        raise CalibrationError("the points do not determine a projection (coplanar or degenerate)")
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.inv(T2) @ Pn @ T3
    _, depth = project(P, X)
    if np.median(depth) < 0:
        P = -P
    return P / np.linalg.norm(P[2, :3])


def decompose(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (upper triangular, positive diagonal, K[2, 2] = 1), R (proper rotation), t from a (3, 4) P.

    Uses ``cv2.decomposeProjectionMatrix`` (RQ decomposition).
    """
    P = np.asarray(P, np.float64)
    if np.linalg.det(P[:, :3]) < 0:
        P = -P
    K, R, C, *_ = cv2.decomposeProjectionMatrix(P)
    K = np.asarray(K, np.float64)
    R = np.asarray(R, np.float64)
    # make the diagonal of K positive (flip matching rows of R)
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R
    if np.linalg.det(R) < 0:  # pragma: no cover - det(P[:, :3]) > 0 rules this out
        R = -R
    K = K / K[2, 2]
    C = (C[:3] / C[3]).reshape(3)
    return K, R, -R @ C




def _calib_flags(*, principal: bool = True, aspect: bool = True) -> int:
    f = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2
         | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5 | cv2.CALIB_FIX_K6)
    if not principal:
        f |= cv2.CALIB_FIX_PRINCIPAL_POINT
    if not aspect:
        f |= cv2.CALIB_FIX_ASPECT_RATIO
    return f


def _refine(X: np.ndarray, x: np.ndarray, size: tuple[int, int], K0: np.ndarray, *, principal: bool = True,
            aspect: bool = True) -> Pinhole:
    """cv2.calibrateCamera from a guess (pinhole, no distortion) -> Pinhole."""
    obj = [np.ascontiguousarray(X, np.float32).reshape(-1, 1, 3)]
    img = [np.ascontiguousarray(x, np.float32).reshape(-1, 1, 2)]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    try:
        _, K, _, rvecs, tvecs = cv2.calibrateCamera(obj, img, tuple(int(v) for v in size), K0.copy(), np.zeros(5),
                                                   flags=_calib_flags(principal=principal, aspect=aspect), criteria=crit)
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV could not refine the calibration: {exc.err or exc}") from exc
    R, _ = cv2.Rodrigues(rvecs[0])
    return Pinhole(K, R, np.asarray(tvecs[0]).reshape(3), size)


def residuals(device: Pinhole | np.ndarray, X: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Reprojection distances (N,) float64 of world points X (N, 3) against pixels x (N, 2)."""
    P = device.P if isinstance(device, Pinhole) else device
    px, depth = project(P, X)
    d = np.linalg.norm(px - np.asarray(x, np.float64), axis=1)
    return np.where(depth > 0, d, np.inf)


@dataclass(frozen=True, eq=False)
class DeviceFit:
    """A calibrated device: its model, residual statistics (px) over the inliers, and the inlier mask."""

    device: Pinhole
    rms: float
    max: float
    count: int
    inliers: np.ndarray


def _fit_stats(device: Pinhole, X, x, inl) -> DeviceFit:
    r = residuals(device, X[inl], x[inl])
    return DeviceFit(device, float(np.sqrt(np.mean(r ** 2))), float(r.max()), int(inl.sum()), inl)


def calibrate_projector(X: np.ndarray, x: np.ndarray, size: tuple[int, int], *, threshold: float = 2.0,
                        max_points: int = 20_000, rounds: int = 3, seed: int = 0) -> DeviceFit:
    """Intrinsics and pose of a projector (or camera) from world <-> pixel correspondences.

    Normalised DLT for the initial guess (on a robust core: the points whose
    DLT residual is below the median-based threshold), then
    ``cv2.calibrateCamera`` with ``CALIB_USE_INTRINSIC_GUESS`` (pinhole, zero
    distortion, free principal point and aspect), trimming points beyond
    ``threshold`` px and refitting ``rounds`` times.

    Parameters
    ----------
    X : (N, 3) float64 world mm, not all coplanar
    x : (N, 2) float64 pixels (e.g. decoded integer projector pixels)
    size : (w, h) of the device
    threshold : float
        Inlier distance, px.
    max_points : int
        The fit sees at most this many points (an even random subsample);
        statistics are over every inlier.

    Returns
    -------
    DeviceFit; ``device.P`` is the 3x4 pose a node renders with.
    """
    X = np.asarray(X, np.float64)
    x = np.asarray(x, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (len(X), 2):
        raise ValueError(f"need X (N, 3) and x (N, 2), got {X.shape}, {x.shape}")
    if len(X) < 12:
        raise CalibrationError(f"need at least 12 correspondences to calibrate a projector, got {len(X)}")
    rng = np.random.default_rng(seed)
    sub = np.arange(len(X)) if len(X) <= max_points else np.sort(rng.choice(len(X), max_points, replace=False))
    P = dlt(X[sub], x[sub])
    r = residuals(P, X[sub], x[sub])
    core = r <= max(threshold, 3.0 * float(np.median(r)))
    P = dlt(X[sub][core], x[sub][core])
    K0, R0, t0 = decompose(P)
    K0[0, 1] = 0.0
    dev = Pinhole(K0, R0, t0, size)
    inl = np.ones(len(X), bool)
    for _ in range(max(1, rounds)):
        inl = residuals(dev, X, x) <= threshold
        s = np.flatnonzero(inl[sub])
        if len(s) < 12:
            raise CalibrationError(f"only {len(s)} correspondences agree with one projection; the surface "
                                   "model, the camera poses or the decoding are off")
        dev = _refine(X[sub][s], x[sub][s], size, dev.K)
    inl = residuals(dev, X, x) <= threshold
    return _fit_stats(dev, X, x, inl)


def pose_camera(sets: list[PointSet], size: tuple[int, int], *, K: np.ndarray | None = None,
                threshold: float = 4.0) -> DeviceFit:
    """Pose one camera in the world from known world points it sees (table points and/or landmarks).

    Parameters
    ----------
    sets : PointSets of this camera in the world frame
    size : (w, h) of the camera's images
    K : (3, 3) float64, optional
        Known intrinsics; then only the pose is solved (``cv2.solvePnP``).
        Without it: non-coplanar points give a full calibration (DLT, then
        ``cv2.calibrateCamera``); coplanar points (the table alone) give the
        focal length with the principal point at the image centre and square
        pixels (Zhang's constraints for a single view), which needs an oblique
        view (at least :data:`MIN_TILT_DEG`), else :class:`CalibrationError`.
    """
    X = np.vstack([s.xyz for s in sets]) if sets else np.zeros((0, 3))
    x = np.vstack([s.pixels for s in sets]) if sets else np.zeros((0, 2))
    if len(X) < 4:
        raise CalibrationError(f"need at least 4 known points to pose a camera, got {len(X)}")
    planar = bool(np.ptp(X[:, 2]) < 1e-6 * max(1.0, float(np.ptp(X[:, :2]))))
    w, h = size
    if K is not None:
        ok, rvec, tvec = cv2.solvePnP(X, x, np.asarray(K, np.float64), None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise CalibrationError("cannot pose the camera from its known points (solvePnP failed)")
        R, _ = cv2.Rodrigues(rvec)
        dev = Pinhole(np.asarray(K, np.float64), R, tvec.reshape(3), size)
    elif planar:
        f0 = _focal_from_plane(X[:, :2], x, size)
        K0 = np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1.0]])
        dev = _refine(X, x, size, K0, principal=False, aspect=False)
        tilt = math.degrees(math.acos(min(1.0, abs(float(dev.R[2] @ [0.0, 0.0, 1.0])))))
        if tilt < MIN_TILT_DEG:
            raise CalibrationError(
                f"the camera looks almost straight at the table (tilted {tilt:.0f} deg): its focal length cannot be "
                "measured from table points alone; add landmarks on the object, or give the camera's intrinsics")
    else:
        if len(X) < 6:
            raise CalibrationError(f"need at least 6 non-coplanar points to calibrate a camera, got {len(X)}")
        K0, R0, t0 = decompose(dlt(X, x))
        K0[0, 1] = 0.0
        dev = _refine(X, x, size, K0)
    inl = residuals(dev, X, x) <= threshold
    if inl.sum() < 4:
        raise CalibrationError("the camera's known points do not agree with one camera pose (check the points file)")
    return _fit_stats(dev, X, x, inl)


def _focal_from_plane(xy: np.ndarray, px: np.ndarray, size: tuple[int, int]) -> float:
    """Focal length (px) from a plane's homography, principal point at the image centre, square pixels."""
    w, h = size
    H = fit_homography(xy, px, threshold=5.0).H
    c = np.array([[1, 0, -(w - 1) / 2], [0, 1, -(h - 1) / 2], [0, 0, 1.0]])
    A = c @ H
    h1, h2 = A[:, 0], A[:, 1]
    # r1 . r2 = 0 and |r1| = |r2| with K = diag(f, f, 1): two estimates of f^2
    est = []
    d = h1[2] * h2[2]
    if abs(d) > 1e-15:
        est.append(-(h1[0] * h2[0] + h1[1] * h2[1]) / d)
    d = h1[2] ** 2 - h2[2] ** 2
    if abs(d) > 1e-15:
        est.append(-((h1[0] ** 2 + h1[1] ** 2) - (h2[0] ** 2 + h2[1] ** 2)) / d)
    est = [e for e in est if e > 0]
    if not est:
        return float(max(w, h))   # fronto-parallel view: the focal length is unobservable; a normal lens
    return float(math.sqrt(np.mean(est)))


def register_mesh(sets: list[PointSet], cameras: dict[int, Pinhole], *, threshold: float = 6.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Model -> world rigid transform of a mesh from landmarks (model points <-> camera pixels).

    ``cv2.solvePnP`` in the camera with the most landmarks gives the start;
    a joint least-squares over every camera's landmarks refines it.

    Returns
    -------
    R : (3, 3) float64, t : (3,) float64 with ``world = R model + t``; rms reprojection error (px)
    """
    use = [s for s in sets if s.camera in cameras]
    missing = sorted({s.camera for s in sets} - set(cameras))
    if not use:
        raise CalibrationError(f"the landmarks are seen by camera(s) {missing} that are not posed")
    best = max(use, key=len)
    if len(best) < 4:
        raise CalibrationError(f"need at least 4 landmarks in one camera to register the mesh, got {len(best)}")
    cam = cameras[best.camera]
    ok, rvec, tvec, inl = cv2.solvePnPRansac(best.xyz, best.pixels, cam.K, None, reprojectionError=threshold,
                                             flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("cannot register the mesh: its landmarks do not agree with one pose")
    Rc, _ = cv2.Rodrigues(rvec)
    # model -> camera (Rc, tc); camera -> world: X_w = cam.R^T (X_c - cam.t)
    R0 = cam.R.T @ Rc
    t0 = cam.R.T @ (tvec.reshape(3) - cam.t)

    def resid(p):
        R, _ = cv2.Rodrigues(p[:3])
        out = []
        for s in use:
            Xw = s.xyz @ R.T + p[3:]
            px, _ = cameras[s.camera].project(Xw)
            out.append((px - s.pixels).ravel())
        return np.concatenate(out)

    r0, _ = cv2.Rodrigues(R0)
    sol = least_squares(resid, np.concatenate([r0.ravel(), t0]), loss="soft_l1", f_scale=threshold / 3)
    R, _ = cv2.Rodrigues(sol.x[:3])
    r = resid(sol.x).reshape(-1, 2)
    return R, sol.x[3:].copy(), float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


def refine_scene(cameras: dict[int, Pinhole], world: list[PointSet], model: list[PointSet], R: np.ndarray,
                 t: np.ndarray, *, fixed_intrinsics: set[int] = frozenset(), scale: float = 1.0) -> tuple[dict[int, Pinhole], np.ndarray, np.ndarray, float]:
    """Joint least squares over every camera (focal length, principal point, pose) and the mesh's
    model -> world transform, from world points (table, world landmarks) and model landmarks together.

    Staged estimates (:func:`pose_camera`, then :func:`register_mesh`) leave the camera's pose poorly
    fixed when its world points lie on the table (rotation and translation trade off for a plane seen
    from above); the landmarks' depth fixes what the table cannot, and the table fixes where the
    object stands. Robust (soft L1, ``scale`` px) so a mis-clicked point does not pull the solution.

    Returns
    -------
    cameras (refined), R (3, 3), t (3,) with ``world = R model + t``, and the rms reprojection error (px)
    """
    ids = sorted(cameras)
    free = [i for i in ids if i not in fixed_intrinsics]

    def unpack(p):
        out, k = {}, 0
        for i in ids:
            K = cameras[i].K.copy()
            if i in free:
                K[0, 0] = K[1, 1] = p[k]
                K[0, 2], K[1, 2] = p[k + 1], p[k + 2]
                k += 3
            Rc, _ = cv2.Rodrigues(p[k:k + 3])
            out[i] = Pinhole(K, Rc, p[k + 3:k + 6], cameras[i].size)
            k += 6
        Rm, _ = cv2.Rodrigues(p[k:k + 3])
        return out, Rm, p[k + 3:k + 6]

    p0 = []
    for i in ids:
        c = cameras[i]
        if i in free:
            p0 += [0.5 * (c.K[0, 0] + c.K[1, 1]), c.K[0, 2], c.K[1, 2]]
        p0 += list(cv2.Rodrigues(c.R)[0].ravel()) + list(c.t)
    p0 += list(cv2.Rodrigues(np.asarray(R, np.float64))[0].ravel()) + list(np.asarray(t, np.float64).ravel())

    def resid(p):
        cams, Rm, tm = unpack(p)
        out = []
        for s in world:
            if s.camera in cams:
                out.append((cams[s.camera].project(s.xyz)[0] - s.pixels).ravel())
        for s in model:
            if s.camera in cams:
                out.append((cams[s.camera].project(s.xyz @ Rm.T + tm)[0] - s.pixels).ravel())
        return np.concatenate(out)

    sol = least_squares(resid, np.asarray(p0, np.float64), loss="soft_l1", f_scale=scale, x_scale="jac")
    cams, Rm, tm = unpack(sol.x)
    r = resid(sol.x).reshape(-1, 2)
    return cams, Rm, tm, float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


# ---------------------------------------------------------------------- ray casting
def gl_projection(device: Pinhole, *, near: float, far: float) -> np.ndarray:
    """(4, 4) float64 world -> OpenGL clip coordinates such that window pixel (x + 0.5, y + 0.5)
    is image pixel (x, y) and framebuffer row 0 (as read back) is image row 0."""
    if not 0 < near < far:
        raise ValueError("need 0 < near < far")
    w, h = device.size
    K = device.K
    M = np.array([
        [2 * K[0, 0] / w, 2 * K[0, 1] / w, (2 * K[0, 2] + 1) / w - 1, 0.0],
        [0.0, 2 * K[1, 1] / h, (2 * K[1, 2] + 1) / h - 1, 0.0],
        [0.0, 0.0, (far + near) / (far - near), -2 * far * near / (far - near)],
        [0.0, 0.0, 1.0, 0.0],
    ])
    V = np.eye(4)
    V[:3, :3] = device.R
    V[:3, 3] = device.t
    return M @ V


def table_quad(table_mm: tuple[float, float], *, grow: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (4, 3) and faces (2, 3) of the table rectangle at z = 0, centred on the origin."""
    w, h = table_mm[0] / 2 + grow, table_mm[1] / 2 + grow
    v = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]], np.int64)


class SurfaceCaster:
    """Casts camera rays onto a surface (a mesh and/or the table plane) by rasterising it (moderngl, EGL).

    Use from one thread; :meth:`close` when done (or use as a context manager).
    """

    def __init__(self, mesh: MeshData | None, *, table_mm: tuple[float, float] | None = None):
        if mesh is None and table_mm is None:
            raise ValueError("nothing to cast onto: give a mesh, a table or both")
        self.ctx = standalone_context(CalibrationError, "3D calibration")
        parts_v, parts_f, kinds = [], [], []
        n = 0
        if table_mm is not None:
            v, f = table_quad(table_mm)
            parts_v.append(v)
            parts_f.append(f + n)
            kinds.append(np.full(len(v), TABLE, np.float32))
            n += len(v)
        if mesh is not None:
            parts_v.append(mesh.vertices.astype(np.float64))
            parts_f.append(mesh.faces.astype(np.int64) + n)
            kinds.append(np.full(len(mesh.vertices), MESH, np.float32))
        self.vertices = np.vstack(parts_v)
        data = np.column_stack([self.vertices.astype(np.float32), np.concatenate(kinds)]).astype("f4")
        try:
            self.prog = self.ctx.program(vertex_shader=(SHADERS / "surface.vert.glsl").read_text(),
                                         fragment_shader=(SHADERS / "surface.frag.glsl").read_text())
            self.vbo = self.ctx.buffer(data.tobytes())
            self.ibo = self.ctx.buffer(np.vstack(parts_f).astype("u4").tobytes())
            self.vao = self.ctx.vertex_array(self.prog, [(self.vbo, "3f 1f", "in_position", "in_kind")], self.ibo)
        except Exception:
            self.close()
            raise

    def cast(self, device: Pinhole) -> tuple[np.ndarray, np.ndarray]:
        """What each pixel of ``device`` sees.

        Returns
        -------
        points : (H, W, 3) float64 world mm at each pixel centre (NaN where nothing)
        kind : (H, W) uint8: 0 nothing, 1 table, 2 mesh
        """
        w, h = device.size
        depth = (self.vertices @ device.R.T + device.t)[:, 2]
        if depth.max() <= 0:
            return np.full((h, w, 3), np.nan), np.zeros((h, w), np.uint8)
        far = float(depth.max()) * 1.05 + 10.0
        near = max(1.0, float(depth[depth > 0].min()) * 0.5) if np.any(depth > 0) else 1.0
        tex = self.ctx.texture((w, h), 4, dtype="f4")
        rb = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=[tex], depth_attachment=rb)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE)
            self.prog["mvp"].write(gl_projection(device, near=near, far=far).T.astype("f4").tobytes())
            self.vao.render()
            out = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)
        finally:
            fbo.release()
            rb.release()
            tex.release()
        kind = np.rint(out[..., 3]).astype(np.uint8)
        pts = out[..., :3].astype(np.float64)
        pts[kind == 0] = np.nan
        return pts, kind

    def close(self) -> None:
        ctx = getattr(self, "ctx", None)
        if ctx is not None:
            ctx.release()
            self.ctx = None

    def __enter__(self) -> "SurfaceCaster":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def edge_mask(points: np.ndarray, kind: np.ndarray, *, jump_mm: float = 8.0, grow: int = 1) -> np.ndarray:
    """(H, W) bool: pixels on or next to a depth discontinuity or a surface boundary (unreliable rays)."""
    p = np.nan_to_num(points, nan=1e9)
    bad = np.zeros(kind.shape, bool)
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(p, axis=axis), axis=-1) > jump_mm
        k = np.diff(kind.astype(np.int16), axis=axis) != 0
        e = d | k
        if axis == 0:
            bad[1:] |= e
            bad[:-1] |= e
        else:
            bad[:, 1:] |= e
            bad[:, :-1] |= e
    return ndimage.binary_dilation(bad, iterations=grow) if grow else bad


def depth_range(P: np.ndarray, vertices: np.ndarray) -> tuple[float, float]:
    """near, far (mm) bracketing the mesh's depths in front of the device with projection ``P``."""
    _, depth = project(P, vertices)
    M = np.asarray(P)[:, :3]
    scale = float(np.linalg.norm(M[2]))   # depth in mm when the third row is a unit vector
    d = depth[depth > 0] / max(scale, 1e-12)
    if len(d) == 0:
        raise CalibrationError("the mesh is entirely behind the projector")
    near = max(1.0, float(d.min()) * 0.8)
    return near, max(float(d.max()) * 1.25, near * 1.5)
