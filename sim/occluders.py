"""Occluders: analytic solids with exact, vectorised ray tests, and the queries over many of them.

Every solid is convex and answers :meth:`Primitive.interval`: for rays
``o + t d`` (unit ``d``) the parameter interval ``[t_in, t_out]`` inside the
solid (``t_in = inf`` on a miss) and the surface normal at ``t_in``. From it
follow the two questions the room asks:

* does the segment from a surface point to a projector's centre cross a solid
  (:func:`segment_blocked`; shadows), and
* where does a camera ray first hit an occluder (:func:`cast_rays`; the camera
  sees the hand).

An occluder is anything with ``primitives()``: a primitive itself, or a union of
them such as the hand and forearm of :mod:`sim.hand`.
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

import numpy as np

from sim.geometry import rotation_about

_EPS = 1e-12


def _vec3(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must be a 3-vector, got shape {np.shape(v)}")
    return a


def _rays(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins, np.float64)
    d = np.asarray(directions, np.float64)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"origins and directions must both be (N, 3), got {o.shape} and {d.shape}")
    return o, d


class Primitive(abc.ABC):
    """A convex solid in world millimetres."""

    @abc.abstractmethod
    def interval(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ray parameter interval inside the solid.

        Parameters
        ----------
        origins, directions : (N, 3) float64
            Ray origins and unit directions.

        Returns
        -------
        t_in, t_out : (N,) float64
            ``t_in = inf, t_out = -inf`` where the line misses; ``t_in`` may be
            negative (the origin is inside or the solid is behind).
        normal : (N, 3) float64
            Outward unit normal at ``t_in`` (zeros on a miss).
        """

    @abc.abstractmethod
    def interval_from(self, origin: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`interval` for many unit directions from one origin (the fast path).

        Parameters
        ----------
        origin : (3,) float64
        dx, dy, dz : (N,) float32 or float64
            Components of unit directions.

        Returns
        -------
        t_in, t_out : (N,) as :meth:`interval` (no normals).
        """

    @abc.abstractmethod
    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """(centre (3,) float64, radius) enclosing the solid."""

    def cull_spheres(self) -> list[tuple[np.ndarray, float]]:
        """Spheres that together enclose the solid (tighter than one for long shapes)."""
        return [self.bounding_sphere()]

    @abc.abstractmethod
    def lowest_z(self) -> float:
        """Smallest z of the solid (mm)."""

    @abc.abstractmethod
    def moved(self, rotation: np.ndarray, translation: np.ndarray) -> "Primitive":
        """The solid after ``x -> rotation @ x + translation``."""

    def primitives(self) -> tuple["Primitive", ...]:
        return (self,)


@dataclass(frozen=True, eq=False)
class Sphere(Primitive):
    center: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        if self.radius <= 0:
            raise ValueError("radius must be positive")

    def interval(self, origins, directions):
        o, d = _rays(origins, directions)
        oc = o - self.center
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius**2
        disc = b * b - c
        hit = disc >= 0
        root = np.sqrt(np.where(hit, disc, 0.0))
        t_in = np.where(hit, -b - root, np.inf)
        t_out = np.where(hit, -b + root, -np.inf)
        p = o + np.where(hit, t_in, 0.0)[:, None] * d
        n = np.where(hit[:, None], (p - self.center) / self.radius, 0.0)
        return t_in, t_out, n

    def interval_from(self, origin, dx, dy, dz):
        return _sphere_from(np.asarray(origin, np.float64) - self.center, self.radius, dx, dy, dz)

    def bounding_sphere(self):
        return self.center.copy(), float(self.radius)

    def lowest_z(self) -> float:
        return float(self.center[2] - self.radius)

    def moved(self, rotation, translation):
        return Sphere(np.asarray(rotation) @ self.center + translation, self.radius)


@dataclass(frozen=True, eq=False)
class Ellipsoid(Primitive):
    """Ellipsoid with semi-axes ``radii`` along the columns of ``rotation``."""

    center: np.ndarray
    radii: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        r = _vec3(self.radii, "radii")
        if np.any(r <= 0):
            raise ValueError("radii must be positive")
        object.__setattr__(self, "radii", r)
        object.__setattr__(self, "rotation", np.asarray(self.rotation, np.float64).reshape(3, 3))

    def interval(self, origins, directions):
        o, d = _rays(origins, directions)
        inv = (self.rotation / self.radii).T  # world -> unit-sphere frame: S^-1 R^T
        ol = (o - self.center) @ inv.T
        dl = d @ inv.T
        a = np.einsum("ij,ij->i", dl, dl)
        b = np.einsum("ij,ij->i", ol, dl)
        c = np.einsum("ij,ij->i", ol, ol) - 1.0
        disc = b * b - a * c
        hit = disc >= 0
        root = np.sqrt(np.where(hit, disc, 0.0))
        t_in = np.where(hit, (-b - root) / a, np.inf)
        t_out = np.where(hit, (-b + root) / a, -np.inf)
        pl = ol + np.where(hit, t_in, 0.0)[:, None] * dl  # on the unit sphere
        n = (pl / self.radii) @ self.rotation.T  # gradient of the implicit function
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), _EPS)
        return t_in, t_out, np.where(hit[:, None], n, 0.0)

    def interval_from(self, origin, dx, dy, dz):
        M = (self.rotation / self.radii).T
        ol = M @ (np.asarray(origin, np.float64) - self.center)
        lx = M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz
        ly = M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz
        lz = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
        a = lx * lx + ly * ly + lz * lz
        b = ol[0] * lx + ol[1] * ly + ol[2] * lz
        disc = b * b - a * (float(ol @ ol) - 1.0)
        hit = disc >= 0
        root = np.sqrt(np.maximum(disc, 0.0))
        return np.where(hit, (-b - root) / a, np.inf), np.where(hit, (-b + root) / a, -np.inf)

    def bounding_sphere(self):
        return self.center.copy(), float(self.radii.max())

    def lowest_z(self) -> float:
        return float(self.center[2] - math.sqrt(float(np.sum((self.rotation[2] * self.radii) ** 2))))

    def moved(self, rotation, translation):
        rotation = np.asarray(rotation)
        return Ellipsoid(rotation @ self.center + translation, self.radii, rotation @ self.rotation)


@dataclass(frozen=True, eq=False)
class Capsule(Primitive):
    """All points within ``radius`` of the segment ``a``-``b``."""

    a: np.ndarray
    b: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "a", _vec3(self.a, "a"))
        object.__setattr__(self, "b", _vec3(self.b, "b"))
        if self.radius <= 0:
            raise ValueError("radius must be positive")

    def interval(self, origins, directions):
        o, d = _rays(origins, directions)
        t_in, t_out, n = Sphere(self.a, self.radius).interval(o, d)
        t2_in, t2_out, n2 = Sphere(self.b, self.radius).interval(o, d)
        better = t2_in < t_in
        t_in = np.where(better, t2_in, t_in)
        n = np.where(better[:, None], n2, n)
        t_out = np.maximum(t_out, t2_out)
        axis = self.b - self.a
        length = float(np.linalg.norm(axis))
        if length < _EPS:
            return t_in, t_out, n
        w = axis / length
        oc = o - self.a
        dw = d @ w
        ow = oc @ w
        dp = d - dw[:, None] * w
        op = oc - ow[:, None] * w
        qa = np.einsum("ij,ij->i", dp, dp)
        qb = np.einsum("ij,ij->i", dp, op)
        qc = np.einsum("ij,ij->i", op, op) - self.radius**2
        parallel = qa < 1e-12
        disc = qb * qb - qa * qc
        hit = ~parallel & (disc >= 0)
        root = np.sqrt(np.where(hit, disc, 0.0))
        safe_a = np.where(parallel, 1.0, qa)
        c_in = np.where(hit, (-qb - root) / safe_a, np.inf)
        c_out = np.where(hit, (-qb + root) / safe_a, -np.inf)
        inside_parallel = parallel & (qc <= 0)
        c_in = np.where(inside_parallel, -np.inf, c_in)
        c_out = np.where(inside_parallel, np.inf, c_out)
        # Restrict to the slab 0 <= axial coordinate <= length.
        with np.errstate(divide="ignore", invalid="ignore"):
            s0 = (0.0 - ow) / dw
            s1 = (length - ow) / dw
        along = np.abs(dw) > 1e-12
        slab_in = np.where(along, np.minimum(s0, s1), np.where((ow >= 0) & (ow <= length), -np.inf, np.inf))
        slab_out = np.where(along, np.maximum(s0, s1), np.where((ow >= 0) & (ow <= length), np.inf, -np.inf))
        cyl_in = np.maximum(c_in, slab_in)
        cyl_out = np.minimum(c_out, slab_out)
        cyl_hit = cyl_in <= cyl_out
        cyl_in = np.where(cyl_hit, cyl_in, np.inf)
        cyl_out = np.where(cyl_hit, cyl_out, -np.inf)
        p = o + np.where(np.isfinite(cyl_in), cyl_in, 0.0)[:, None] * d - self.a
        radial = p - (p @ w)[:, None] * w
        radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), _EPS)
        better = cyl_in < t_in
        t_in = np.where(better, cyl_in, t_in)
        n = np.where(better[:, None], radial, n)
        t_out = np.maximum(t_out, cyl_out)
        return t_in, t_out, n

    def interval_from(self, origin, dx, dy, dz):
        o = np.asarray(origin, np.float64)
        t_in, t_out = _sphere_from(o - self.a, self.radius, dx, dy, dz)
        t2_in, t2_out = _sphere_from(o - self.b, self.radius, dx, dy, dz)
        t_in = np.minimum(t_in, t2_in)
        t_out = np.maximum(t_out, t2_out)
        axis = self.b - self.a
        length = float(np.linalg.norm(axis))
        if length < _EPS:
            return t_in, t_out
        w = axis / length
        oc = o - self.a
        ow = float(oc @ w)
        op = oc - ow * w
        dw = w[0] * dx + w[1] * dy + w[2] * dz
        qa = np.maximum(1.0 - dw * dw, 0.0)
        qb = op[0] * dx + op[1] * dy + op[2] * dz
        qc = float(op @ op) - self.radius**2
        disc = qb * qb - qa * qc
        ok = (qa > 1e-12) & (disc >= 0)
        root = np.sqrt(np.maximum(disc, 0.0))
        safe_a = np.where(ok, qa, 1.0)
        c_in = np.where(ok, (-qb - root) / safe_a, np.inf)
        c_out = np.where(ok, (-qb + root) / safe_a, -np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            s0 = -ow / dw
            s1 = (length - ow) / dw
        lo = np.maximum(c_in, np.minimum(s0, s1))
        hi = np.minimum(c_out, np.maximum(s0, s1))
        hit = ok & (lo <= hi)
        # Rays parallel to the axis are covered by the end spheres (the capsule's extent along them).
        t_in = np.where(hit, np.minimum(t_in, lo), t_in)
        t_out = np.where(hit, np.maximum(t_out, hi), t_out)
        return t_in, t_out

    def bounding_sphere(self):
        return (self.a + self.b) / 2.0, float(np.linalg.norm(self.b - self.a) / 2.0 + self.radius)

    def cull_spheres(self):
        length = float(np.linalg.norm(self.b - self.a))
        k = max(1, math.ceil(length / (2.0 * self.radius)))
        step = (self.b - self.a) / k
        reach = length / (2 * k) + self.radius
        return [(self.a + (i + 0.5) * step, reach) for i in range(k)]

    def lowest_z(self) -> float:
        return float(min(self.a[2], self.b[2]) - self.radius)

    def moved(self, rotation, translation):
        rotation = np.asarray(rotation)
        return Capsule(rotation @ self.a + translation, rotation @ self.b + translation, self.radius)


@dataclass(frozen=True, eq=False)
class Box(Primitive):
    """A box with half-extents ``size / 2`` along the columns of ``rotation``.

    ``Box(center=(0, 0, 200), size=(100, 60, 2))`` is a thin plate parallel to the table.
    """

    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        s = _vec3(self.size, "size")
        if np.any(s <= 0):
            raise ValueError("size must be positive")
        object.__setattr__(self, "size", s)
        object.__setattr__(self, "rotation", np.asarray(self.rotation, np.float64).reshape(3, 3))

    @classmethod
    def yawed(cls, center, size, yaw_deg: float = 0.0) -> "Box":
        """A box turned by ``yaw_deg`` about the vertical axis."""
        return cls(center, size, rotation_about((0, 0, 1), math.radians(yaw_deg)))

    def corners(self) -> np.ndarray:
        """(8, 3) float64 world corners."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
        return self.center + (signs * self.size / 2.0) @ self.rotation.T

    def interval(self, origins, directions):
        o, d = _rays(origins, directions)
        ol = (o - self.center) @ self.rotation
        dl = d @ self.rotation
        h = self.size / 2.0
        small = np.abs(dl) < 1e-12
        safe = np.where(small, 1.0, dl)
        t1 = (-h - ol) / safe
        t2 = (h - ol) / safe
        lo = np.where(small, np.where(np.abs(ol) <= h, -np.inf, np.inf), np.minimum(t1, t2))
        hi = np.where(small, np.where(np.abs(ol) <= h, np.inf, -np.inf), np.maximum(t1, t2))
        t_in = lo.max(axis=1)
        t_out = hi.min(axis=1)
        hit = t_in <= t_out
        k = lo.argmax(axis=1)
        nl = np.zeros_like(ol)
        nl[np.arange(len(ol)), k] = -np.sign(dl[np.arange(len(ol)), k])
        n = nl @ self.rotation.T
        return np.where(hit, t_in, np.inf), np.where(hit, t_out, -np.inf), np.where(hit[:, None], n, 0.0)

    def interval_from(self, origin, dx, dy, dz):
        R = self.rotation
        ol = R.T @ (np.asarray(origin, np.float64) - self.center)
        h = self.size / 2.0
        t_in = np.full(np.shape(dx), -np.inf)
        t_out = np.full(np.shape(dx), np.inf)
        for k in range(3):
            dl = R[0, k] * dx + R[1, k] * dy + R[2, k] * dz
            small = np.abs(dl) < 1e-12
            safe = np.where(small, 1.0, dl)
            t1 = (-h[k] - ol[k]) / safe
            t2 = (h[k] - ol[k]) / safe
            inside = abs(ol[k]) <= h[k]
            lo = np.where(small, -np.inf if inside else np.inf, np.minimum(t1, t2))
            hi = np.where(small, np.inf if inside else -np.inf, np.maximum(t1, t2))
            t_in = np.maximum(t_in, lo)
            t_out = np.minimum(t_out, hi)
        hit = t_in <= t_out
        return np.where(hit, t_in, np.inf), np.where(hit, t_out, -np.inf)

    def bounding_sphere(self):
        return self.center.copy(), float(np.linalg.norm(self.size) / 2.0)

    def lowest_z(self) -> float:
        return float(self.corners()[:, 2].min())

    def moved(self, rotation, translation):
        rotation = np.asarray(rotation)
        return Box(rotation @ self.center + translation, self.size, rotation @ self.rotation)


def _sphere_from(oc: np.ndarray, radius: float, dx, dy, dz):
    b = oc[0] * dx + oc[1] * dy + oc[2] * dz
    disc = b * b - (float(oc @ oc) - radius * radius)
    hit = disc >= 0
    root = np.sqrt(np.maximum(disc, 0.0))
    return np.where(hit, -b - root, np.inf), np.where(hit, -b + root, -np.inf)


# ---------------------------------------------------------------- queries over many solids


def flatten(occluders) -> list[Primitive]:
    """All primitives of a list of occluders (primitives, hands, ...)."""
    out: list[Primitive] = []
    for occ in occluders:
        out.extend(occ.primitives())
    return out


def segment_blocked(starts: np.ndarray, ends: np.ndarray, primitives, *, eps: float = 1e-6) -> np.ndarray:
    """Whether the open segment ``start -> end`` crosses any primitive.

    Parameters
    ----------
    starts, ends : (N, 3) float64
        E.g. surface points and a projector's optical centre.

    Returns
    -------
    (N,) bool
    """
    a = np.asarray(starts, np.float64)
    b = np.asarray(ends, np.float64)
    if a.ndim == 1:
        a = np.broadcast_to(a, b.shape)
    if b.ndim == 1:
        b = np.broadcast_to(b, a.shape)
    v = b - a
    length = np.linalg.norm(v, axis=1)
    d = v / np.maximum(length, _EPS)[:, None]
    blocked = np.zeros(len(a), dtype=bool)
    for prim in primitives:
        t_in, t_out, _ = prim.interval(a, d)
        blocked |= (t_in < length - eps) & (t_out > eps)
    return blocked


def cast_rays(origins: np.ndarray, directions: np.ndarray, primitives) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays (from outside) with any primitive.

    Returns
    -------
    t : (N,) float64, ``inf`` where nothing is hit
    normal : (N, 3) float64
    """
    o, d = _rays(origins, directions)
    best = np.full(len(o), np.inf)
    normal = np.zeros((len(o), 3))
    for prim in primitives:
        t_in, t_out, n = prim.interval(o, d)
        ok = (t_in > 0) & (t_in <= t_out) & (t_in < best)
        best = np.where(ok, t_in, best)
        normal = np.where(ok[:, None], n, normal)
    return best, normal


def bounding_sphere(primitives) -> tuple[np.ndarray, float]:
    """A sphere enclosing all primitives (centre of the spheres' box, max reach)."""
    spheres = [p.bounding_sphere() for p in primitives]
    centers = np.array([c for c, _ in spheres])
    mid = (centers.min(axis=0) + centers.max(axis=0)) / 2.0
    radius = max(float(np.linalg.norm(c - mid)) + r for c, r in spheres)
    return mid, radius
