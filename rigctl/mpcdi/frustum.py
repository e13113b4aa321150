"""A projector's 3x4 projection matrix as MPCDI describes a projector: a frustum (yaw, pitch and
roll, then the angles of its four edges) and a position.

World frame (the rig's): millimetres, z up, the table the plane z = 0; x along the content's
rows, y towards the content's top row. MPCDI's coordinateFrame is written for it: the pitch axis
(right) is +x, the roll axis (forward) +y, the yaw axis (down) -z, positions in metres.

Angles follow MPCDI: from facing +y, the projector turns right by ``yaw`` degrees, tilts up by
``pitch``, then rolls by ``roll`` (positive lifts its left side); ``leftAngle``/``rightAngle``/
``upAngle``/``downAngle`` are the degrees from its axis to the outer edges of its border pixels
(left and down negative for a centred lens). A pinhole with square-cornered pixels (no skew) is
described exactly; skew is not expressible and is reported.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frustum:
    """MPCDI's description of one projector (degrees; position in metres)."""

    yaw: float
    pitch: float
    roll: float
    left: float
    right: float
    up: float
    down: float
    position_m: tuple[float, float, float]
    skew: float = 0.0      # K[0, 1] / K[0, 0] of the matrix it came from (0 when expressible)


def normalised(p: np.ndarray) -> np.ndarray:
    """(3, 4) float64: ``p`` scaled so its third row's first three entries have unit length and
    its left 3x3 block a positive determinant (a projection matrix is defined up to scale)."""
    p = np.asarray(p, np.float64)
    p = p / np.linalg.norm(p[2, :3])
    return -p if np.linalg.det(p[:, :3]) < 0 else p


def decompose(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``p`` (3, 4) -> K (3, 3) upper triangular with K[2, 2] = 1 and a positive diagonal,
    R (3, 3) a rotation (world -> projector, rows right, down, forward), C (3,) the centre (mm)."""
    from scipy.linalg import rq   # the coordinator's stack

    p = normalised(p)
    m = p[:, :3]
    k, r = rq(m)
    signs = np.diag(np.sign(np.diag(k)))
    k, r = k @ signs, signs @ r          # signs @ signs = I: the product is unchanged
    if np.linalg.det(r) < 0:             # cannot happen with det(m) > 0 and diag(k) > 0
        raise ValueError("projection matrix is not a rotation times a camera matrix")
    c = -np.linalg.solve(m, p[:, 3])
    return k / k[2, 2], r, c


def to_frustum(p: np.ndarray, width: int, height: int) -> Frustum:
    """The MPCDI frustum of projection matrix ``p`` for a ``width`` x ``height`` projector."""
    k, r, c = decompose(p)
    fx, s, cx, fy, cy = k[0, 0], k[0, 1], k[0, 2], k[1, 1], k[1, 2]
    right_v, fwd = r[0], r[2]          # rows: right, down, forward
    yaw = math.atan2(fwd[0], fwd[1])
    pitch = math.asin(max(-1.0, min(1.0, fwd[2])))
    r0 = np.array([math.cos(yaw), -math.sin(yaw), 0.0])
    up0 = np.cross(r0, fwd)
    roll = math.atan2(-float(right_v @ up0), float(right_v @ r0))
    deg = math.degrees
    return Frustum(
        yaw=deg(yaw), pitch=deg(pitch), roll=deg(roll),
        left=deg(math.atan((-0.5 - cx) / fx)), right=deg(math.atan((width - 0.5 - cx) / fx)),
        up=deg(math.atan((cy + 0.5) / fy)), down=deg(math.atan((cy - height + 0.5) / fy)),
        position_m=(c[0] / 1000.0, c[1] / 1000.0, c[2] / 1000.0), skew=float(s / fx))


def from_frustum(f: Frustum, width: int, height: int) -> np.ndarray:
    """The (3, 4) projection matrix (normalised, see :func:`normalised`) of frustum ``f``."""
    rad = math.radians
    tl, tr, tu, td = (math.tan(rad(a)) for a in (f.left, f.right, f.up, f.down))
    if not (tr > tl and tu > td):
        raise ValueError(f"frustum edges out of order: left {f.left}, right {f.right}, up {f.up}, down {f.down}")
    fx = width / (tr - tl)
    fy = height / (tu - td)
    k = np.array([[fx, f.skew * fx, -0.5 - fx * tl], [0.0, fy, fy * tu - 0.5], [0.0, 0.0, 1.0]])
    y, p, ro = rad(f.yaw), rad(f.pitch), rad(f.roll)
    fwd = np.array([math.sin(y) * math.cos(p), math.cos(y) * math.cos(p), math.sin(p)])
    r0 = np.array([math.cos(y), -math.sin(y), 0.0])
    up0 = np.cross(r0, fwd)
    right_v = r0 * math.cos(ro) - up0 * math.sin(ro)
    up_v = up0 * math.cos(ro) + r0 * math.sin(ro)
    r = np.stack([right_v, -up_v, fwd])
    c = np.array(f.position_m, np.float64) * 1000.0
    return normalised(k @ np.concatenate([r, (-r @ c)[:, None]], axis=1))
