"""Coverage of a 3D surface: which projectors reach each point of it, and with what share of the light.

On a 3D object the shadow a hand casts depends on how many projectors reach the point it
hides (the paper's coverage figure, section 5.1.2): where every projector reaches, blocking a
few removes a small share; where two reach, blocking one halves the light. An operator has
the calibrated 3x4 poses and the mesh; from them alone this module computes, per point of the
surface:

* whether projector *i* **reaches** it: the point lies inside the projector's image
  (``-0.5 <= u <= w - 0.5`` and the same for v, pixel centres at integers), in front of it,
  faces it (``n . (C - X) > 0``) and is not hidden by the mesh itself (a shadow map: the mesh's
  depth rendered from the projector at ``shadow_scale`` times its resolution, with OpenGL,
  :mod:`coordinator.coverage_gl`);
* the **irradiance** it gets from projector *i* at full white (the model)::

      E_i = g_i * cos(theta_i) * (d0 / d_i)^2 * cos(alpha_i)^(f - 3)

  with ``theta_i`` the incidence angle (surface normal to the ray), ``d_i`` the distance
  (mm, ``d0`` = 1000 mm), ``alpha_i`` the ray's angle off the projector's optical axis and
  ``g_i`` the projector's gain (the slot's gain: what the rig scales its output by). A pinhole
  projector showing uniform white sends equal flux through each pixel and a pixel ``alpha`` off
  the axis spans a solid angle proportional to ``cos^3(alpha)``, hence the ``cos^-3``; ``f``
  (``falloff``, default 1) is the lens's fall-off towards the edge, ``cos^f``. Units cancel in
  the shares. Projectors are assumed equally bright at equal gain: a unit's own peak output
  is not something the poses tell;
* the **count** ``N = sum_i reach_i`` and each projector's **share** ``s_i = E_i / sum_j E_j``;
  ``max_i s_i`` is the light drop when the brightest single projector there is blocked, and
  ``1 / sum_i s_i^2`` the **effective number** of projectors (as many equally bright ones
  would give the same spread).

The surface is sampled per texel of the mesh's UV texture (:meth:`CoverageModel.texture`:
one sample per content texel a triangle covers, the texel's share of the surface in mm^2
beside it), or at any points (:meth:`CoverageModel.at_points`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imaging.calibration.threed import Pinhole, decompose
from coordinator.coverage_gl import CoverageRaster, scaled_device

__all__ = ["Projector", "PointCoverage", "Coverage", "CoverageModel", "projector_from_pose", "irradiance",
           "REFERENCE_MM", "DEFAULT_TEXTURE", "DEFAULT_SHADOW_SCALE"]

#: the distance at which a fronto-parallel surface on a projector's axis gets E = gain
REFERENCE_MM = 1000.0
DEFAULT_TEXTURE = (512, 512)
#: shadow-map pixels per projector pixel and axis
DEFAULT_SHADOW_SCALE = 2
#: points at most this far (mm) behind the shadow map's nearest surface still count as that surface
BIAS_MM = 1.0
#: the slope part of the bias, in shadow-map pixels' footprints per unit of tan(incidence)
BIAS_SLOPE = 2.0
BIAS_MAX_MM = 25.0


@dataclass(frozen=True, eq=False)
class Projector:
    """One projector as coverage sees it: its slot, its posed pinhole (size = its output) and gain."""

    slot: str
    device: Pinhole
    gain: float = 1.0


def projector_from_pose(slot: str, matrix: np.ndarray, size: tuple[int, int], *, gain: float = 1.0) -> Projector:
    """A :class:`Projector` from a (3, 4) pose (world mm -> projector px) and its output ``size`` (w, h)."""
    K, R, t = decompose(np.asarray(matrix, np.float64))
    return Projector(slot, Pinhole(K, R, t, size), float(gain))


def _geometry(device: Pinhole, X: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cos(incidence), cos(off-axis) and distance (n,) float64 of points X (n, 3) with normals n (n, 3)."""
    to_c = device.center - X
    d = np.linalg.norm(to_c, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_t = np.einsum("ij,ij->i", n, to_c) / d
        cos_a = (X @ device.R[2] + device.t[2]) / d          # depth / distance (K's last row is 0 0 1)
    return cos_t, cos_a, d


def irradiance(device: Pinhole, points: np.ndarray, normals: np.ndarray, *, gain: float = 1.0,
               falloff: float = 1.0) -> np.ndarray:
    """The model's full-white irradiance ``E`` (module docstring) at points, zero where the
    surface faces away or lies behind the projector (visibility is not tested here).

    Parameters
    ----------
    points, normals : (n, 3) float64 world mm and unit normals

    Returns
    -------
    (n,) float64
    """
    X = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    if X.shape != n.shape:
        raise ValueError(f"points and normals must both be (n, 3), got {X.shape} and {n.shape}")
    cos_t, cos_a, d = _geometry(device, X, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = gain * cos_t * (REFERENCE_MM / d) ** 2 * np.power(cos_a, falloff - 3.0)
    return np.where((cos_t > 0) & (cos_a > 1e-6) & np.isfinite(e), e, 0.0)


@dataclass(frozen=True, eq=False)
class PointCoverage:
    """Coverage at a list of points.

    Attributes
    ----------
    slots : the projectors, in order
    reach : (S, n) bool
    irradiance : (S, n) float64, zero where not reached
    """

    slots: tuple[str, ...]
    reach: np.ndarray
    irradiance: np.ndarray

    @property
    def count(self) -> np.ndarray:
        """(n,) int64 projectors reaching each point."""
        return self.reach.sum(axis=0)

    @property
    def share(self) -> np.ndarray:
        """(S, n) float64: each projector's share of the light (0 where no light at all)."""
        return _shares(self.irradiance)

    @property
    def effective(self) -> np.ndarray:
        """(n,) float64: ``1 / sum_i share_i^2`` (0 where no light)."""
        return _effective(self.share)


def _shares(e: np.ndarray) -> np.ndarray:
    total = e.sum(axis=0, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, e / np.where(total > 0, total, 1.0), 0.0)


def _effective(s: np.ndarray) -> np.ndarray:
    q = (s.astype(np.float64) ** 2).sum(axis=0)
    with np.errstate(divide="ignore"):
        return np.where(q > 0, 1.0 / np.where(q > 0, q, 1.0), 0.0)


@dataclass(frozen=True, eq=False)
class Coverage:
    """Coverage per texel of a (w, h) texture of the mesh.

    Attributes
    ----------
    slots : the projectors, in order (S of them)
    mask : (h, w) bool, texels a triangle covers (the sampled surface)
    area : (h, w) float32 mm^2 of surface per texel (0 off the surface)
    points, normals : (h, w, 3) float32 the surface at each texel centre
    reach : (S, h, w) bool
    irradiance : (S, h, w) float32, zero where not reached
    model : how it was computed (falloff, shadow scale, gains)
    """

    slots: tuple[str, ...]
    mask: np.ndarray
    area: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    reach: np.ndarray
    irradiance: np.ndarray
    model: dict = field(default_factory=dict)

    @property
    def size(self) -> tuple[int, int]:
        return int(self.mask.shape[1]), int(self.mask.shape[0])

    @property
    def count(self) -> np.ndarray:
        """(h, w) int16 projectors reaching each texel (0 off the surface)."""
        return self.reach.sum(axis=0).astype(np.int16)

    @property
    def share(self) -> np.ndarray:
        """(S, h, w) float32 each projector's share of the light at each texel."""
        return _shares(self.irradiance.astype(np.float64)).astype(np.float32)

    @property
    def max_share(self) -> np.ndarray:
        """(h, w) float32: the light lost where the brightest projector of the texel is blocked."""
        return self.share.max(axis=0) if len(self.slots) else np.zeros(self.mask.shape, np.float32)

    @property
    def effective(self) -> np.ndarray:
        """(h, w) float32 effective number of projectors (0 where no light)."""
        return _effective(self.share).astype(np.float32)

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Texel (row, col) of content uvs (..., 2) in [0, 1] (nearest texel, clipped to the texture): (..., 2) int64."""
        w, h = self.size
        uv = np.asarray(uv, np.float64)
        col = np.clip(np.floor(np.nan_to_num(uv[..., 0]) * w), 0, w - 1).astype(np.int64)
        row = np.clip(np.floor(np.nan_to_num(uv[..., 1]) * h), 0, h - 1).astype(np.int64)
        return np.stack([row, col], axis=-1)

    def summary(self) -> dict:
        """The figures an operator reads: the surface, the distribution of the count over it (by
        area) and, per slot, how much of it the projector reaches and its mean share there."""
        a = np.where(self.mask, self.area, 0.0).astype(np.float64)
        total = float(a.sum())
        count = self.count
        lit = self.mask & (count > 0)
        lit_area = float(a[lit].sum())
        share = self.share
        eff = self.effective
        S = len(self.slots)
        hist = np.bincount(count[self.mask].ravel(), weights=a[self.mask].ravel(), minlength=S + 1)
        order = np.argsort(count[lit].ravel(), kind="stable")
        cum = np.cumsum(a[lit].ravel()[order])

        def quantile(q: float) -> int | None:
            if not len(cum):
                return None
            return int(count[lit].ravel()[order][min(len(cum) - 1, int(np.searchsorted(cum, q * cum[-1])))])

        per_slot = {}
        for k, slot in enumerate(self.slots):
            r = self.reach[k] & self.mask
            ra = float(a[r].sum())
            only = r & (count == 1)
            per_slot[slot] = {
                "reach_mm2": round(ra, 1),
                "reach_pct": _pct(ra, total),
                "reach_pct_of_lit": _pct(ra, lit_area),
                "mean_share_pct": round(100.0 * float((share[k] * a)[r].sum()) / ra, 2) if ra > 0 else None,
                "sole_mm2": round(float(a[only].sum()), 1),
            }
        return {
            "texture": list(self.size),
            "slots": len(self.slots),
            "surface_mm2": round(total, 1),
            "lit_pct": _pct(lit_area, total),
            "count_area_mm2": {str(k): round(float(v), 1) for k, v in enumerate(hist) if v > 0},
            "count_mean": round(float((count * a)[lit].sum()) / lit_area, 3) if lit_area > 0 else None,
            "count_min": int(count[lit].min()) if lit.any() else None,
            "count_p5": quantile(0.05),
            "count_median": quantile(0.5),
            "effective_mean": round(float((eff * a)[lit].sum()) / lit_area, 3) if lit_area > 0 else None,
            "max_share_mean_pct": round(100.0 * float((self.max_share * a)[lit].sum()) / lit_area, 2) if lit_area > 0 else None,
            "model": self.model,
            "per_slot": per_slot,
        }


def _pct(part: float, whole: float) -> float | None:
    return round(100.0 * part / whole, 2) if whole > 0 else None


class CoverageModel:
    """The mesh and the projectors, with one shadow map per projector rendered up front.

    Parameters
    ----------
    vertices : (V, 3) float32 world mm; faces : (F, 3) uint32; uvs : (V, 2) float32 in [0, 1]
    projectors : the projectors (their poses and gains)
    shadow_scale : shadow-map pixels per projector pixel and axis
    falloff : the lens fall-off exponent ``f`` of the model

    Use from one thread; :meth:`close` when done (or use it as a context manager).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, projectors: list[Projector], *,
                 shadow_scale: int = DEFAULT_SHADOW_SCALE, falloff: float = 1.0):
        if not projectors:
            raise ValueError("coverage needs at least one projector")
        slots = [p.slot for p in projectors]
        if len(set(slots)) != len(slots):
            raise ValueError(f"duplicate slots in {slots}")
        if not 1 <= int(shadow_scale) <= 8:
            raise ValueError("shadow_scale must be 1..8")
        if not math.isfinite(falloff):
            raise ValueError("falloff must be finite")
        self.projectors = list(projectors)
        self.slots = tuple(slots)
        self.shadow_scale = int(shadow_scale)
        self.falloff = float(falloff)
        self.raster = CoverageRaster(vertices, faces, uvs)
        try:
            self._maps = []
            for p in self.projectors:
                dev = scaled_device(p.device, self.shadow_scale)
                self._maps.append((dev, self.raster.depth_map(dev)))
        except Exception:
            self.close()
            raise

    @property
    def model(self) -> dict:
        return {"irradiance": "E = gain * cos(incidence) * (1000 mm / distance)^2 * cos(off-axis)^(falloff - 3)",
                "falloff": self.falloff, "shadow_scale": self.shadow_scale,
                "gains": {p.slot: p.gain for p in self.projectors}}

    def _reach_one(self, k: int, cols: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Reach (n,) bool and irradiance (n,) float64 of projector ``k`` at points given as six
        (n,) float64 columns: x, y, z and the normal's x, y, z (component-wise: several times
        faster than (n, 3) matrix products on this many points)."""
        p = self.projectors[k]
        dev, depth = self._maps[k]
        w, h = p.device.size
        X, Y, Z, NX, NY, NZ = cols
        P = p.device.P
        c = p.device.center
        vx, vy, vz = c[0] - X, c[1] - Y, c[2] - Z
        d2 = vx * vx + vy * vy + vz * vz
        d = np.sqrt(d2)
        hz = P[2, 0] * X + P[2, 1] * Y + P[2, 2] * Z + P[2, 3]        # depth (mm): K's last row is 0 0 1
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (P[0, 0] * X + P[0, 1] * Y + P[0, 2] * Z + P[0, 3]) / hz
            v = (P[1, 0] * X + P[1, 1] * Y + P[1, 2] * Z + P[1, 3]) / hz
            cos_t = (NX * vx + NY * vy + NZ * vz) / d
            cos_a = hz / d
            e = cos_t * (REFERENCE_MM * REFERENCE_MM / d2) * np.power(cos_a, self.falloff - 3.0)
            ok = ((hz > 0) & (cos_t > 0) & (cos_a > 1e-6) & np.isfinite(e)
                  & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5))
        idx = np.flatnonzero(ok)
        if len(idx):
            s = self.shadow_scale
            qx, qy, zq = s * (u[idx] + 0.5) - 0.5, s * (v[idx] + 0.5) - 0.5, hz[idx]   # shadow-map pixels
            H, W = depth.shape
            # the 2 x 2 shadow-map pixels around the point; it is hidden only if all four are nearer
            x0 = np.clip(np.floor(qx).astype(np.int64), 0, W - 2)
            y0 = np.clip(np.floor(qy).astype(np.int64), 0, H - 2)
            far = np.maximum.reduce([depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]])
            ct = np.clip(cos_t[idx], 0.02, 1.0)
            tan_t = np.sqrt(1.0 - ct * ct) / ct
            pixel_mm = zq / dev.K[0, 0]          # one shadow-map pixel's footprint, fronto-parallel
            bias = np.minimum(BIAS_MM + BIAS_SLOPE * pixel_mm * tan_t, BIAS_MAX_MM)
            ok[idx] = zq <= far + bias
        return ok, np.where(ok, e * p.gain, 0.0)

    def at_points(self, points: np.ndarray, normals: np.ndarray) -> PointCoverage:
        """Coverage at points (n, 3) world mm with unit normals (n, 3) (outwards)."""
        X = np.asarray(points, np.float64).reshape(-1, 3)
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        if X.shape != n.shape:
            raise ValueError(f"points and normals must both be (n, 3), got {X.shape} and {n.shape}")
        S = len(self.projectors)
        reach = np.zeros((S, len(X)), bool)
        e = np.zeros((S, len(X)))
        good = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(n), axis=1)
        cols = tuple(np.ascontiguousarray(a[good, j]) for a in (X, n) for j in range(3))
        for k in range(S):
            reach[k, good], e[k, good] = self._reach_one(k, cols)
        return PointCoverage(self.slots, reach, e)

    def texture(self, size: tuple[int, int] = DEFAULT_TEXTURE) -> Coverage:
        """Coverage at every texel centre of a ``size`` = (w, h) texture of the mesh."""
        w, h = int(size[0]), int(size[1])
        if not (8 <= w <= 8192 and 8 <= h <= 8192):
            raise ValueError(f"texture size must be 8..8192 per side, got {w}x{h}")
        pts, nrm, face, hit = self.raster.texels((w, h))
        area = np.zeros((h, w), np.float32)
        area[hit] = texel_area(self.raster.vertices, self.raster.faces, self.raster.uvs, (w, h))[face[hit]]
        mask = hit & (area > 0)
        pc = self.at_points(pts[mask], nrm[mask])
        S = len(self.projectors)
        reach = np.zeros((S, h, w), bool)
        e = np.zeros((S, h, w), np.float32)
        reach[:, mask] = pc.reach
        e[:, mask] = pc.irradiance
        return Coverage(self.slots, mask, np.where(mask, area, 0.0).astype(np.float32), pts, nrm, reach, e,
                        {**self.model, "texture": [w, h]})

    def close(self) -> None:
        raster = getattr(self, "raster", None)
        if raster is not None:
            raster.close()

    def __enter__(self) -> "CoverageModel":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def texel_area(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(F,) float64 mm^2 of surface per texel of a (w, h) texture on each triangle: its world area
    over its area in texels (0 for a triangle with no area in UV space)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    uv = np.asarray(uvs, np.float64) * np.asarray(size, np.float64)
    tri = v[f]
    world = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    t = uv[f]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    texels = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(texels > 1e-12, world / np.where(texels > 1e-12, texels, 1.0), 0.0)
