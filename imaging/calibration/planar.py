"""Planar calibration numerics: the table <-> camera mapping, robust homographies,
and the composition into each node's content -> projector pose.

Spaces (docs/architecture.md, "Coordinate spaces"): ``content`` pixels, ``table`` millimetres (the
world plane z = 0), ``camera`` and ``projector`` pixels. All homographies are
(3, 3) float64 mapping source pixel coordinates to destination coordinates as
``cv2.warpPerspective`` uses them, normalised so ``H[2, 2] = 1``.

The content image spans the table rectangle: with a table of ``W x H`` mm
centred on the origin and content of ``w x h`` pixels, content x runs along
world +x and content y along world -y (the table seen from above, row 0 at
the +y edge), pixel centres at integers::

    x_mm = W (x + 0.5) / w - W / 2        y_mm = H / 2 - H (y + 0.5) / h

(:func:`protos.spaces.content_to_table`, the convention every process shares; re-exported here.)

A node's pose is then ``H_content->projector = H_camera->projector @
H_table->camera @ H_content->table`` (the paper's ``H_w2c H_c2p`` composed with
the content placement).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imaging.calibration.errors import CalibrationError
from protos.spaces import content_to_table

# OpenCV is imported inside the functions that use it: the operator's command line imports
# CharucoSpec (through coordinator.calibration.options) and must run without the coordinator
# extra's heavy libraries.

__all__ = ["normalise", "apply_homography", "content_to_table", "compose_pose", "HomographyFit", "fit_homography",
           "pixel_centroids", "table_to_camera_from_points", "homography_difference", "CharucoSpec", "detect_charuco"]


def _points(a, name: str) -> np.ndarray:
    p = np.asarray(a, np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must be (N, 2), got {p.shape}")
    return p


def normalise(H: np.ndarray) -> np.ndarray:
    """``H`` as (3, 3) float64 scaled so ``H[2, 2] = 1``; CalibrationError when degenerate."""
    H = np.asarray(H, np.float64)
    if H.shape != (3, 3):
        raise ValueError(f"a homography must be (3, 3), got {H.shape}")
    if not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-15:
        raise CalibrationError("the homography is degenerate (points collinear or too few)")
    return H / H[2, 2]


def apply_homography(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points through ``H``.

    Parameters
    ----------
    H : (3, 3) float64
    points : (N, 2) float64

    Returns
    -------
    (N, 2) float64; NaN where the point maps to infinity.
    """
    p = _points(points, "points")
    q = p @ np.asarray(H, np.float64)[:, :2].T + np.asarray(H, np.float64)[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = q[:, :2] / q[:, 2:3]
    out[~np.isfinite(out).all(axis=1)] = np.nan
    return out


def compose_pose(camera_to_projector: np.ndarray, table_to_camera: np.ndarray, *, content_size: tuple[int, int],
                 table_mm: tuple[float, float]) -> np.ndarray:
    """A node's planar pose: (3, 3) float64 content px -> projector px."""
    H = np.asarray(camera_to_projector, np.float64) @ np.asarray(table_to_camera, np.float64) @ content_to_table(content_size, table_mm)
    return normalise(H)


@dataclass(frozen=True, eq=False)
class HomographyFit:
    """A robustly fitted homography.

    Attributes
    ----------
    H : (3, 3) float64, source -> destination
    inliers : (N,) bool
    rms, max : float
        Residuals (destination units) over the inliers.
    count : int
        Number of inliers.
    """

    H: np.ndarray
    inliers: np.ndarray
    rms: float
    max: float
    count: int
    residuals: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))


def fit_homography(src: np.ndarray, dst: np.ndarray, *, threshold: float = 1.5, confidence: float = 0.999,
                   max_points: int = 60_000, refine_rounds: int = 2, seed: int = 0) -> HomographyFit:
    """Robust homography ``dst ~ H src``: USAC-MAGSAC++ (RANSAC for small sets) for the inliers, then least squares
    with Levenberg-Marquardt refinement (``cv2.findHomography`` method 0) on them.

    Parameters
    ----------
    src, dst : (N, 2) float64
        Correspondences; residuals are measured in ``dst`` units, so put the
        noisy side (e.g. decoded projector pixels) in ``dst``.
    threshold : float
        Inlier distance in ``dst`` units for the robust stage and for the
        trimming after each refinement.
    max_points : int
        The robust stage sees at most this many points (an even subsample);
        every point is re-classified against the refined model.

    Returns
    -------
    HomographyFit

    Raises
    ------
    CalibrationError
        Fewer than 4 points, or no consistent homography.
    """
    import cv2

    s, d = _points(src, "src"), _points(dst, "dst")
    if len(s) != len(d):
        raise ValueError(f"src and dst differ in length: {len(s)} vs {len(d)}")
    if len(s) < 4:
        raise CalibrationError(f"need at least 4 correspondences for a homography, got {len(s)}")
    idx = np.arange(len(s))
    if len(s) > max_points:
        idx = np.random.default_rng(seed).choice(len(s), max_points, replace=False)
        idx.sort()
    H = None
    try:
        # USAC-MAGSAC++ for dense sets; classic RANSAC for small ones (OpenCV's USAC gives up on a few dozen points)
        if len(idx) >= 50:
            H, _ = cv2.findHomography(s[idx], d[idx], cv2.USAC_MAGSAC, threshold, maxIters=5000, confidence=confidence)
        if H is None:
            H, _ = cv2.findHomography(s[idx], d[idx], cv2.RANSAC, threshold, maxIters=5000, confidence=confidence)
    except cv2.error as exc:
        raise CalibrationError(f"homography estimation failed: {exc.err or exc}") from exc
    if H is None:
        raise CalibrationError(f"no consistent homography among {len(s)} correspondences")
    H = normalise(H)
    inl = np.zeros(len(s), bool)
    for _ in range(max(1, refine_rounds)):
        res = np.linalg.norm(apply_homography(H, s) - d, axis=1)
        inl = np.nan_to_num(res, nan=np.inf) <= threshold
        if inl.sum() < 4:
            raise CalibrationError(f"only {int(inl.sum())} of {len(s)} correspondences agree with one homography")
        sub = np.flatnonzero(inl)
        if len(sub) > 4 * max_points:   # the LM refinement does not need every pixel
            sub = sub[:: len(sub) // (4 * max_points) + 1]
        try:
            H2, _ = cv2.findHomography(s[sub], d[sub], 0)
        except cv2.error as exc:
            raise CalibrationError(f"homography refinement failed: {exc.err or exc}") from exc
        if H2 is None:
            raise CalibrationError("homography refinement failed (degenerate inliers)")
        H = normalise(H2)
    res = np.linalg.norm(apply_homography(H, s) - d, axis=1)
    inl = np.nan_to_num(res, nan=np.inf) <= threshold
    r = res[inl]
    return HomographyFit(H, inl, float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan"),
                         float(r.max()) if len(r) else float("nan"), int(inl.sum()), res)


def pixel_centroids(camera: np.ndarray, projector: np.ndarray, *, min_samples: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Aggregate dense correspondences per projector pixel: the mean camera position of the camera
    pixels that decoded to each projector pixel (a sub-pixel camera point for an exact projector pixel).

    Parameters
    ----------
    camera : (N, 2) float64 camera pixels
    projector : (N, 2) float64 integer projector pixels
    min_samples : int
        Projector pixels seen by fewer camera pixels (mask edges) are left out.

    Returns
    -------
    camera_means : (M, 2) float64
    projector_pixels : (M, 2) float64
    """
    cam, proj = _points(camera, "camera"), _points(projector, "projector")
    if len(cam) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    keys = proj.astype(np.int64)
    key = keys[:, 1] * (int(keys[:, 0].max()) + 1) + keys[:, 0]
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    sums = np.zeros((len(uniq), 2))
    np.add.at(sums, inv, cam)
    first = np.zeros(len(uniq), np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    keep = counts >= min_samples
    return sums[keep] / counts[keep, None], proj[first[keep]]


def table_to_camera_from_points(table_xy: np.ndarray, pixels: np.ndarray, *, threshold: float = 3.0) -> HomographyFit:
    """Table mm (x, y) -> camera px from known points (clicked marks or detected board corners).

    Raises
    ------
    CalibrationError
        Fewer than 4 points, or the points do not fit one plane-to-image mapping.
    """
    t, p = _points(table_xy, "table_xy"), _points(pixels, "pixels")
    if len(t) < 4:
        raise CalibrationError(f"need at least 4 known table points to map the table into the camera, got {len(t)}")
    span = np.ptp(t, axis=0)
    if np.min(span) <= 1e-6 or np.linalg.matrix_rank(np.column_stack([t - t.mean(0)])) < 2:
        raise CalibrationError("the known table points are collinear; spread them over the table (e.g. its corners)")
    return fit_homography(t, p, threshold=threshold)


def homography_difference(H_est: np.ndarray, H_ref: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """RMS and max distance between ``H_est`` and ``H_ref`` images of ``points`` (N, 2)."""
    a, b = apply_homography(H_est, points), apply_homography(H_ref, points)
    d = np.linalg.norm(a - b, axis=1)
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(d ** 2))), float(d.max())


# ---------------------------------------------------------------------- ChArUco
@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board lying on the table.

    ``origin_mm`` is the table position (x, y) of the board's chessboard corner
    at board coordinates (0, 0) (OpenCV's top-left); the board's x axis runs
    along table +x and its y axis along table -y (the board is read the right
    way up from above, like the content image). ``dictionary`` is an OpenCV
    ArUco dictionary name, e.g. ``DICT_5X5_100``.
    """

    squares_x: int = 11
    squares_y: int = 7
    square_mm: float = 50.0
    marker_mm: float = 37.0
    dictionary: str = "DICT_5X5_100"
    origin_mm: tuple[float, float] = (-275.0, 175.0)
    legacy: bool = False

    @classmethod
    def from_dict(cls, doc: dict) -> "CharucoSpec":
        known = {f for f in cls.__dataclass_fields__}
        unknown = set(doc) - known
        if unknown:
            raise CalibrationError(f"unknown ChArUco board key(s) {sorted(unknown)} (known: {sorted(known)})")
        spec = cls(**{k: (tuple(v) if k == "origin_mm" else v) for k, v in doc.items()})
        if spec.squares_x < 2 or spec.squares_y < 2 or not 0 < spec.marker_mm < spec.square_mm:
            raise CalibrationError("a ChArUco board needs >= 2x2 squares and 0 < marker_mm < square_mm")
        return spec

    def board(self):
        import cv2

        name = self.dictionary.upper()
        if not hasattr(cv2.aruco, name):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_5X5_100, DICT_4X4_250)")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        board = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), float(self.square_mm), float(self.marker_mm), dictionary)
        board.setLegacyPattern(bool(self.legacy))
        return board

    def board_to_table(self, board_xy: np.ndarray) -> np.ndarray:
        """(N, 2) board mm -> (N, 2) table mm."""
        b = _points(board_xy, "board_xy")
        return np.column_stack([self.origin_mm[0] + b[:, 0], self.origin_mm[1] - b[:, 1]])


def detect_charuco(image: np.ndarray, spec: CharucoSpec, *, min_corners: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Find the board's chessboard corners (sub-pixel) in a camera image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) float32 in [0, 1] (or uint8)

    Returns
    -------
    table_xy : (N, 2) float64 table mm of the corners found
    pixels : (N, 2) float64 camera pixels

    Raises
    ------
    CalibrationError
        Fewer than ``min_corners`` corners found.
    """
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = img.mean(axis=2)
    if img.ndim != 2:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got {np.shape(image)}")
    if img.dtype != np.uint8:
        f = img.astype(np.float32)
        lo, hi = np.percentile(f, 0.5), np.percentile(f, 99.5)
        img = np.clip((f - lo) / max(hi - lo, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    board = spec.board()
    params = cv2.aruco.CharucoParameters()
    det_params = cv2.aruco.DetectorParameters()
    det_params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.CharucoDetector(board, params, det_params)
    try:
        corners, ids, _, _ = detector.detectBoard(img)
    except cv2.error as exc:
        raise CalibrationError(f"ChArUco detection failed: {exc.err or exc}") from exc
    n = 0 if ids is None else len(ids)
    if n < min_corners:
        raise CalibrationError(f"the ChArUco board was not found in the camera image ({n} corners, need {min_corners}): "
                               "check that it lies flat in view, is lit, and matches the board in the parameters")
    ids = ids.reshape(-1)
    board_pts = np.asarray(board.getChessboardCorners(), np.float64)[ids, :2]
    return spec.board_to_table(board_pts), corners.reshape(-1, 2).astype(np.float64)
