"""The coordinate-space conventions every process shares, defined once.

A pose travels on the wire as a matrix; what a node does with it is part of the
contract between coordinator and node, so it is defined here, beside the wire,
where the coordinator, the node, the room and the benchmarks may all read it:

* :func:`content_to_table`: where content pixels lie on the table (content spans the
  table, centred on the world origin, content x along world +x, content rows along
  world -y, texel centres at integer coordinates).
* :func:`projector_samples` and :func:`bilinear_taps`: the node's content lookup. Projector
  pixel ``(u, v)`` shows the content at ``pose^-1 (u, v, 1)``, interpolated bilinearly
  between the four texels around it (OpenCV's convention: texel ``(x, y)`` has its centre at
  integer ``(x, y)``), texels outside the content counting as 0. This is
  ``cv2.warpPerspective(..., INTER_LINEAR, BORDER_CONSTANT, 0)``; the node's shader
  (``node/render/pipeline.glsl``) computes exactly this, and the node's tests check it
  against :func:`warp_content`.
* :func:`lut_lookup`: the node's luminance pipeline, ``LUT(clip(gain * value))`` per channel
  with linear interpolation between the ``E`` LUT samples at ``k / (E - 1)``, output
  quantised to ``round(255 * value)``.
* :func:`blend_sample`, :func:`dither_thresholds` and :func:`blended_output`: the same pipeline
  with a projector's blend maps (:mod:`protos.blend`), ``LUT(clip(gain * (alpha * value +
  beta)))``, the maps interpolated bilinearly from their grid and the output quantised with a 4x4
  ordered (Bayer) dither, ``floor(255 * value + t)``, so that a slow ramp scaled by the maps does
  not band in 8 bits.
* :func:`look_at`, :func:`intrinsics`, :func:`scale_intrinsics`: a pinhole device in the world
  (``x ~ K (R X + t)``, OpenCV's axes, pixel centres at integers) aimed at a point, and the same
  optics sampled at another resolution; the room builds its devices with them and the
  coordinator a layout's planned poses (:mod:`protos.layout`).

Only numpy: this module is part of every install, the edge node's included.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["content_to_table", "output_outline", "projector_samples", "bilinear_taps", "warp_content", "lut_lookup",
           "quantise", "as_linear", "blend_sample", "dither_thresholds", "blended_output", "intrinsics",
           "scale_intrinsics", "look_at"]


def content_to_table(content_size: Sequence[int], table_mm: Sequence[float]) -> np.ndarray:
    """(3, 3) float64: content pixels -> table millimetres, the content spanning the table.

    ``x_mm = W_mm (x + 0.5) / w - W_mm / 2`` and ``y_mm = H_mm / 2 - H_mm (y + 0.5) / h``.

    Parameters
    ----------
    content_size : (w, h)
        Content size in pixels.
    table_mm : (W_mm, H_mm)
        Table size in millimetres.
    """
    w, h = (int(v) for v in content_size)
    tw, th = (float(v) for v in table_mm)
    if w <= 0 or h <= 0 or tw <= 0 or th <= 0:
        raise ValueError(f"content size and table size must be positive, got {tuple(content_size)}, {tuple(table_mm)}")
    return np.array([[tw / w, 0.0, tw / (2 * w) - tw / 2], [0.0, -th / h, th / 2 - th / (2 * h)], [0.0, 0.0, 1.0]])


def output_outline(pose: np.ndarray, projector_size: Sequence[int], content_size: Sequence[int]) -> np.ndarray | None:
    """Where a projector's output lands in content pixels: (4, 2) float64, the output rectangle's
    corners (pixel edges) through the inverse of its (3, 3) content px -> projector px ``pose``;
    None when the pose is singular or a corner lies beyond the horizon (it cannot be drawn)."""
    H = np.asarray(pose, np.float64)
    try:
        inv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    cw, ch = content_size
    # a homography is defined up to sign: the content lies where the pose sends its centre
    if (H @ np.array([(cw - 1) / 2.0, (ch - 1) / 2.0, 1.0]))[2] < 0:
        inv = -inv
    w, h = projector_size
    corners = np.array([[-0.5, -0.5, 1.0], [w - 0.5, -0.5, 1.0], [w - 0.5, h - 0.5, 1.0], [-0.5, h - 0.5, 1.0]]).T
    q = inv @ corners
    if np.any(q[2] <= 1e-12):
        return None
    xy = (q[:2] / q[2]).T
    return xy if np.all(np.isfinite(xy)) else None


def projector_samples(pose: np.ndarray, projector_size: Sequence[int], *,
                      content_size: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where each projector pixel samples the content: ``(x, y)``, each ``(h, w) float64``.

    Pixels whose ray misses the content plane (beyond the horizon, or not finite) get
    ``-10``, which :func:`bilinear_taps` treats as outside. A homography is defined up to
    scale, sign included: with ``content_size`` the side of the horizon where the content
    lies is the one where the pose sends the content's centre (as the node's shader does);
    without it, where the pose's third row is positive.

    Parameters
    ----------
    pose : (3, 3) float
        Content px -> projector px.
    projector_size : (w, h)
    content_size : (W, H), optional
    """
    H = np.asarray(pose, np.float64)
    if H.shape != (3, 3):
        raise ValueError(f"pose must be (3, 3), got {H.shape}")
    w, h = (int(v) for v in projector_size)
    if w <= 0 or h <= 0:
        raise ValueError(f"projector size must be positive, got {tuple(projector_size)}")
    inv = np.linalg.inv(H)
    if content_size is not None:
        cw, ch = (float(v) for v in content_size)
        if (H @ np.array([(cw - 1) / 2.0, (ch - 1) / 2.0, 1.0]))[2] < 0:
            inv = -inv
    v, u = np.mgrid[0:h, 0:w]
    q = inv @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q[0] / q[2], q[1] / q[2]
    ok = (q[2] > 0) & np.isfinite(x) & np.isfinite(y)
    return np.where(ok, x, -10.0).reshape(h, w), np.where(ok, y, -10.0).reshape(h, w)


def bilinear_taps(x: np.ndarray, y: np.ndarray, content_size: Sequence[int]):
    """The four texels and weights of a bilinear lookup at content coordinates ``(x, y)``.

    Returns a list of four ``(index, weight)`` pairs, each ``(n,) int64`` flat texel index
    ``Y * w + X`` and ``(n,) float64`` weight, for the ``n = x.size`` lookups in order;
    a texel outside the content has weight 0 (and index 0).
    """
    cw, ch = (int(v) for v in content_size)
    x = np.asarray(x, np.float64).ravel()
    y = np.asarray(y, np.float64).ravel()
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    taps = []
    for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        X, Y = x0 + dx, y0 + dy
        inside = (X >= 0) & (X < cw) & (Y >= 0) & (Y < ch)
        taps.append((np.where(inside, Y * cw + X, 0), np.where(inside, wt, 0.0)))
    return taps


def as_linear(image: np.ndarray) -> np.ndarray:
    """Content as linear float32: uint8 / 255, uint16 / 65535, floats unchanged."""
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / np.float32(255)
    if a.dtype == np.uint16:
        return a.astype(np.float32) / np.float32(65535)
    return a.astype(np.float32, copy=False)


def lut_lookup(lut: np.ndarray | None, values: np.ndarray, *, gain: float = 1.0) -> np.ndarray:
    """The node's luminance pipeline: ``round(255 * clip(LUT(clip(gain * values))))`` as uint8,
    halves rounded up (as the shader quantises).

    Parameters
    ----------
    lut : (C, E) float, or None for the identity
        Inverse-response LUT: row ``c`` samples channel ``c`` at ``k / (E - 1)``.
    values : (H, W), (H, W, C) or (n,) / (n, C) float
        Linear luminance; a 2-D array is treated as one channel when ``C == 1``.
    """
    table = np.array([[0.0, 1.0]], np.float64) if lut is None else np.asarray(lut, dtype=np.float64)
    if table.ndim != 2 or table.shape[1] < 2:
        raise ValueError(f"lut must be (C, E) with E >= 2, got {table.shape}")
    c, e = table.shape
    vals = np.clip(np.asarray(values, dtype=np.float64) * gain, 0.0, 1.0)
    grid = np.linspace(0.0, 1.0, e)
    if c == 1 and (vals.ndim < 3 or vals.shape[-1] != 1):
        out = np.interp(vals, grid, table[0])
    else:
        if vals.shape[-1] != c:
            raise ValueError(f"values have {vals.shape[-1]} channels, the LUT {c}")
        out = np.empty_like(vals)
        for ch in range(c):
            out[..., ch] = np.interp(vals[..., ch], grid, table[ch])
    return quantise(out)


def quantise(values: np.ndarray) -> np.ndarray:
    """Linear values to 8-bit output levels as the node does: ``floor(255 * clip(v) + 0.5)``, uint8."""
    return np.floor(np.clip(np.asarray(values, np.float64), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def warp_content(content: np.ndarray, pose: np.ndarray, projector_size: Sequence[int], *,
                 lut: np.ndarray | None = None, gain: float = 1.0, apply_lut: bool = True,
                 blend: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """What a node outputs for ``content``, computed with numpy: ``(h, w, 3) uint8``.

    The content lookup of :func:`projector_samples` / :func:`bilinear_taps`, then, when
    ``apply_lut``, ``gain`` and the inverse-response LUT (:func:`lut_lookup`), or with ``blend``
    the blended pipeline of :func:`blended_output`; otherwise just ``round(255 * clip(value))``
    (no blend either). Grey content (1 or 2 channels) is replicated to RGB.

    Parameters
    ----------
    content : (H, W) or (H, W, C) float32/uint8/uint16
        Linear content (integers are normalised by their maximum value).
    pose : (3, 3) float64
        Content px -> projector px.
    projector_size : (w, h)
    lut : (C, E) float, optional
        Inverse-response LUT (None: identity).
    blend : (alpha (m, n, 3), beta (m, n)) float, optional
        The projector's blend maps on their own grid (see :func:`blend_sample`).
    """
    img = as_linear(content)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3:
        raise ValueError(f"content must be (H, W) or (H, W, C), got {img.shape}")
    ch, cw = img.shape[:2]
    img = img[:, :, :1] if img.shape[2] < 3 else img[:, :, :3]
    w, h = (int(v) for v in projector_size)
    x, y = projector_samples(pose, (w, h), content_size=(cw, ch))
    flat = img.reshape(ch * cw, -1)
    out = np.zeros((h * w, flat.shape[1]), np.float64)
    for index, weight in bilinear_taps(x, y, (cw, ch)):
        out += weight[:, None] * flat[index]
    warped = out.reshape(h, w, -1).astype(np.float32)
    if warped.shape[2] == 1:
        warped = np.repeat(warped, 3, axis=2)
    if not apply_lut:
        return quantise(warped)
    table = None if lut is None else np.asarray(lut, np.float32)
    if table is not None and table.shape[0] == 1:
        table = np.repeat(table, 3, axis=0)
    if table is None:
        table = np.array([[0.0, 1.0]] * 3, np.float32)
    if blend is not None:
        return blended_output(warped, blend[0], blend[1], lut=table, gain=gain)
    return lut_lookup(table, warped, gain=gain)


# ---------------------------------------------------------------- blend maps


def blend_sample(alpha: np.ndarray, beta: np.ndarray, projector_size: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """A projector's blend maps at every one of its pixels, as its node samples them.

    The maps are a downscaled image of the output frame (:mod:`protos.blend`): texel ``(i, j)`` of an
    ``(m, n)`` map has its centre at projector pixel ``((j + 0.5) W / n - 0.5, (i + 0.5) H / m - 0.5)``,
    so projector pixel ``(x, y)`` reads the map at ``((x + 0.5) n / W - 0.5, (y + 0.5) m / H - 0.5)``,
    interpolated bilinearly between the four texels around it, indices clamped to the map (its edge
    texels extend to the frame's border): what a texture unit's LINEAR filter with CLAMP_TO_EDGE
    computes, which the node uses (node/render/blend_texture.py). The node holds the maps' float16
    values, as the wire carries them: they are rounded to float16 here too.

    Parameters
    ----------
    alpha : (m, n, 3) float
    beta : (m, n) float
    projector_size : (W, H)

    Returns
    -------
    alpha : (H, W, 3) float64
    beta : (H, W) float64
    """
    a = np.asarray(alpha, np.float16).astype(np.float64)
    b = np.asarray(beta, np.float16).astype(np.float64)
    if a.ndim != 3 or a.shape[2] != 3 or b.shape != a.shape[:2]:
        raise ValueError(f"blend maps must be alpha (m, n, 3) and beta (m, n), got {a.shape} and {b.shape}")
    m, n = b.shape
    w, h = (int(v) for v in projector_size)
    if w <= 0 or h <= 0:
        raise ValueError(f"projector size must be positive, got {tuple(projector_size)}")
    # float32, as the shader computes the map coordinates of a fragment
    mx = (np.arange(w, dtype=np.float32) + np.float32(0.5)) * np.float32(n / w) - np.float32(0.5)
    my = (np.arange(h, dtype=np.float32) + np.float32(0.5)) * np.float32(m / h) - np.float32(0.5)
    x0, y0 = np.floor(mx), np.floor(my)
    fx, fy = (mx - x0).astype(np.float64), (my - y0).astype(np.float64)
    xa, xb = np.clip(x0.astype(np.int64), 0, n - 1), np.clip(x0.astype(np.int64) + 1, 0, n - 1)
    ya, yb = np.clip(y0.astype(np.int64), 0, m - 1), np.clip(y0.astype(np.int64) + 1, 0, m - 1)
    stack = np.concatenate([a, b[:, :, None]], axis=2)                       # (m, n, 4)
    top = stack[ya][:, xa] * (1 - fx)[None, :, None] + stack[ya][:, xb] * fx[None, :, None]
    bottom = stack[yb][:, xa] * (1 - fx)[None, :, None] + stack[yb][:, xb] * fx[None, :, None]
    out = top * (1 - fy)[:, None, None] + bottom * fy[:, None, None]
    return out[:, :, :3], out[:, :, 3]


#: the 4x4 Bayer matrix: the order in which a 4x4 block's pixels step up to the next level
BAYER4 = np.array([[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]], np.int64)


def dither_thresholds(projector_size: Sequence[int]) -> np.ndarray:
    """(H, W) float64: the ordered dither's threshold at each projector pixel, ``(B + 0.5) / 16``
    with ``B = BAYER4[y % 4, x % 4]`` (rows counted from the top of the output), in (0, 1)."""
    w, h = (int(v) for v in projector_size)
    y, x = np.mgrid[0:h, 0:w]
    return (BAYER4[y % 4, x % 4] + 0.5) / 16.0


def blended_output(values: np.ndarray, alpha: np.ndarray, beta: np.ndarray, *, lut: np.ndarray | None = None,
                   gain: float = 1.0) -> np.ndarray:
    """What a node with blend maps outputs for linear ``values`` already in its pixels: ``(H, W, 3) uint8``.

    ``v = LUT(clip(gain * (alpha * values + beta)))`` per channel (the maps through
    :func:`blend_sample`, the LUT as :func:`lut_lookup` interpolates it), then the 8-bit level
    ``floor(255 * clip(v) + t)`` with ``t`` the ordered dither's threshold at the pixel
    (:func:`dither_thresholds`): a value ``k + f`` levels up shows ``k + 1`` on a share ``f`` of
    each 4x4 block, so the block's mean keeps the fraction that rounding would lose.

    Parameters
    ----------
    values : (H, W, 3) float
        Linear content in projector pixels (the output of the warp).
    alpha : (m, n, 3) float in [0, 1]
    beta : (m, n) float in [0, 1]
    lut : (C, E) float, optional
        Inverse-response LUT, C in {1, 3} (None: identity).
    """
    vals = np.asarray(values, np.float64)
    if vals.ndim != 3 or vals.shape[2] != 3:
        raise ValueError(f"values must be (H, W, 3), got {vals.shape}")
    h, w = vals.shape[:2]
    a, b = blend_sample(alpha, beta, (w, h))
    lin = np.clip(gain * (a * vals + b[:, :, None]), 0.0, 1.0)
    table = np.array([[0.0, 1.0]] * 3) if lut is None else np.asarray(lut, np.float64)
    if table.ndim != 2 or table.shape[0] not in (1, 3) or table.shape[1] < 2:
        raise ValueError(f"lut must be (C, E) with C in {{1, 3}} and E >= 2, got {table.shape}")
    if table.shape[0] == 1:
        table = np.repeat(table, 3, axis=0)
    grid = np.linspace(0.0, 1.0, table.shape[1])
    out = np.empty_like(lin)
    for ch in range(3):
        out[..., ch] = np.interp(lin[..., ch], grid, table[ch])
    t = dither_thresholds((w, h))
    return np.floor(np.clip(out, 0.0, 1.0) * 255.0 + t[:, :, None]).astype(np.uint8)


# ---------------------------------------------------------------- devices in the world


def intrinsics(size: tuple[int, int], *, focal: float | tuple[float, float], principal: tuple[float, float] | None = None) -> np.ndarray:
    """Intrinsic matrix for an image of ``size`` = (width, height).

    Parameters
    ----------
    size : (int, int)
        Width and height in pixels.
    focal : float or (float, float)
        Focal length in pixels (fx, fy).
    principal : (float, float), optional
        Principal point in pixel coordinates; default the image centre
        ``((w - 1) / 2, (h - 1) / 2)``.

    Returns
    -------
    K : (3, 3) float64
    """
    w, h = size
    if w <= 0 or h <= 0:
        raise ValueError(f"size must be positive, got {size}")
    fx, fy = (focal, focal) if np.isscalar(focal) else focal
    if fx <= 0 or fy <= 0:
        raise ValueError(f"focal length must be positive, got {focal}")
    cx, cy = ((w - 1) / 2.0, (h - 1) / 2.0) if principal is None else principal
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def scale_intrinsics(K: np.ndarray, from_size: tuple[int, int], to_size: tuple[int, int]) -> np.ndarray:
    """Intrinsics of the same optics sampled at another resolution.

    The image area is kept: pixel centres move as ``x' = sx (x + 0.5) - 0.5``
    with ``sx = w' / w`` (same for y), so a resized image stays registered.

    Returns
    -------
    K' : (3, 3) float64
    """
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K must be (3, 3), got {K.shape}")
    sx = to_size[0] / from_size[0]
    sy = to_size[1] / from_size[1]
    S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
    return S @ K


def look_at(eye, target, *, up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation of a device at ``eye`` looking at ``target``.

    ``up`` is the world direction that appears towards the top of the image
    (image -y). For a device looking straight down on the table with the
    default ``up = +y``, image x runs along world +x and image y along world -y.

    Returns
    -------
    R : (3, 3) float64
        World-to-device rotation (rows: device x, y, z axes in world coordinates).
    t : (3,) float64
        ``-R @ eye``.
    """
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    if eye.shape != (3,) or target.shape != (3,) or up.shape != (3,):
        raise ValueError("eye, target and up must be 3-vectors")
    z = target - eye
    norm = np.linalg.norm(z)
    if norm == 0:
        raise ValueError("eye and target coincide")
    z /= norm
    x = np.cross(-up, z)  # so that image y (= z cross x) points along -up
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("up is parallel to the viewing direction; choose another up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ eye
