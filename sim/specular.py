"""A glossy material for the room: an energy-normalised Blinn-Phong specular lobe on chosen surfaces.

Off by default: a :class:`~sim.scene.Scene` has ``gloss=()`` and the room renders exactly as it
always did. With ``gloss=(Gloss("table", 0.1, 0.03),)`` every camera (an observer among them,
:func:`sim.observer.with_observer`) sees, on top of the table's diffuse light, each projector's
highlight: the reflection of its lens.

The model
---------
A projector lens is a point light at its optical centre. At a surface point ``p`` with unit
normal ``N``, ``L`` the unit direction to the lens, ``V`` the unit direction to the camera and
``H = (L + V) / |L + V|`` the half vector, the specular BRDF is Blinn-Phong's with the usual
energy normalisation::

    f_s = k_s (n + 8) / (8 pi) (N.H)^n        (zero where N.L <= 0 or N.V <= 0)

``k_s`` is the gloss's ``strength`` (the share of the light the lobe reflects, 0..1) and ``n`` the
exponent of its ``roughness`` alpha, ``n = 2 / alpha^2 - 2`` (the exponent whose lobe matches
Beckmann's of roughness alpha near its peak). The room's diffuse signal of a point is
``albedo x irradiance`` (a Lambertian surface reflects ``albedo / pi`` per steradian, the
camera's gain takes the ``pi``), so the lobe adds ``pi f_s x irradiance`` beside it, from the
same irradiance (distance, incidence, lens fall-off, hot spot, blur, shadows) and with the same
blur: :func:`reflectance` is ``pi f_s``, a number comparable to an albedo. There is no Fresnel
term and no shadowing-masking term: ``k_s`` is constant, which suits a varnished table or a
glazed object away from grazing angles.

Why Blinn-Phong and not GGX: the lobe's peak, ``k_s (n + 8) / (8 pi)`` at ``N.H = 1``, does not
depend on the light's direction, and near its peak the lobe is a Gaussian in the half-vector angle
(``(N.H)^n ~ exp(-n a^2 / 2)``), so a highlight's peak and its area above a threshold have closed
forms (``bench specular`` tests the room against them). Its tail falls off as fast as a Gaussian:
where the next lens of a 250 mm array 1.4 m up has its highlight, the half vector has turned about
0.09 rad, and one lens's lobe is below 2e-4 of its peak there at roughness 0.03 (1e-8 at 0.02), so
the highlights of a rig stay apart; GGX's tail falls off as a power of the angle and would lay a
floor of every lens's light between them. Normalisation: ``(n + 8) / (8 pi)`` makes the
lobe reflect about ``k_s`` of the light for any ``n`` (at normal incidence ``k_s (1 + 1.8 / n)``:
2 % too much at ``n = 100``, 0.04 % at the default 0.02's ``n = 4998``; ``tests/sim/test_specular.py``
integrates it).

Shapes: ``points``, ``normals`` are ``(n, 3)`` float64 or ``(x, y, z)`` tuples of ``(n,)`` arrays;
``light``, ``eye`` are ``(3,)`` float64 world mm; every result is ``(n,)`` float64.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SURFACES", "Gloss", "parse_gloss", "blinn_phong_exponent", "reflectance", "SpecularView", "specular_view"]

#: Surfaces a gloss can be put on: the table, or the room's mesh (the bust or a loaded object).
SURFACES = ("table", "mesh")


def blinn_phong_exponent(roughness: float) -> float:
    """Blinn-Phong's exponent ``n = 2 / alpha^2 - 2`` of roughness ``alpha`` in (0, 1]."""
    return 2.0 / (roughness * roughness) - 2.0


@dataclass(frozen=True)
class Gloss:
    """A glossy coat on one surface of the room.

    Attributes
    ----------
    surface : "table" or "mesh"
    strength : float in [0, 1]
        ``k_s``: the share of the light the specular lobe reflects (0: no highlight at all).
    roughness : float in (0, 1]
        ``alpha``: 0.02 a varnished table (a sharp highlight), 0.05 satin, 0.3 a dull sheen, 1 almost matte.
    """

    surface: str
    strength: float
    roughness: float

    def __post_init__(self) -> None:
        if self.surface not in SURFACES:
            raise ValueError(f"gloss surface {self.surface!r} is not one of {', '.join(SURFACES)}")
        if not (isinstance(self.strength, (int, float)) and 0.0 <= self.strength <= 1.0):
            raise ValueError(f"gloss strength must be a number from 0 to 1 (the share of the light the lobe reflects), got {self.strength!r}")
        if not (isinstance(self.roughness, (int, float)) and 0.0 < self.roughness <= 1.0):
            raise ValueError(f"gloss roughness must be a number above 0 and at most 1 (0.02 a varnished table), got {self.roughness!r}")
        object.__setattr__(self, "strength", float(self.strength))
        object.__setattr__(self, "roughness", float(self.roughness))

    @property
    def exponent(self) -> float:
        """Blinn-Phong's exponent ``n`` of this roughness."""
        return blinn_phong_exponent(self.roughness)

    @property
    def peak(self) -> float:
        """``pi f_s`` at the lobe's peak (``N.H = 1``): ``k_s (n + 8) / 8``."""
        return self.strength * (self.exponent + 8.0) / 8.0

    def __str__(self) -> str:
        return f"{self.surface}:{self.strength:g}:{self.roughness:g}"


def parse_gloss(text: str) -> Gloss:
    """``"SURFACE:STRENGTH:ROUGHNESS"`` (e.g. ``"table:0.1:0.03"``) -> :class:`Gloss`.

    Raises
    ------
    ValueError
        One line naming what is wrong.
    """
    parts = str(text).split(":")
    if len(parts) != 3:
        raise ValueError(f"gloss {text!r} must be SURFACE:STRENGTH:ROUGHNESS, e.g. table:0.1:0.03")
    surface, strength, roughness = parts
    try:
        ks, alpha = float(strength), float(roughness)
    except ValueError:
        raise ValueError(f"gloss {text!r}: strength and roughness must be numbers, e.g. table:0.1:0.03") from None
    if not (math.isfinite(ks) and math.isfinite(alpha)):
        raise ValueError(f"gloss {text!r}: strength and roughness must be finite numbers")
    return Gloss(surface.strip(), ks, alpha)


def _soa(a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if isinstance(a, tuple):
        return a
    a = np.asarray(a, np.float64)
    return a[..., 0], a[..., 1], a[..., 2]


def reflectance(light, eye, points, normals, strength, exponent) -> np.ndarray:
    """``pi f_s``: what the lobe adds to the albedo at each point, for a point light at ``light``.

    Parameters
    ----------
    light, eye : (3,) float64
        The lens's and the camera's centres, world mm.
    points, normals : (n, 3) float64 or tuples of three (n,) arrays
        Surface points and their unit normals.
    strength, exponent : float or (n,) float64
        ``k_s`` and Blinn-Phong's ``n`` (per point, or one for all).

    Returns
    -------
    (n,) float64 ``k_s (n + 8) / 8 (N.H)^n``; 0 where the light or the eye is behind the surface.
    """
    X, Y, Z = _soa(points)
    NX, NY, NZ = _soa(normals)
    lx, ly, lz = (float(v) for v in light)
    ex, ey, ez = (float(v) for v in eye)
    Lx, Ly, Lz = lx - X, ly - Y, lz - Z
    Vx, Vy, Vz = ex - X, ey - Y, ez - Z
    with np.errstate(divide="ignore", invalid="ignore"):
        dl = np.sqrt(Lx * Lx + Ly * Ly + Lz * Lz)
        dv = np.sqrt(Vx * Vx + Vy * Vy + Vz * Vz)
        Lx, Ly, Lz = Lx / dl, Ly / dl, Lz / dl
        Vx, Vy, Vz = Vx / dv, Vy / dv, Vz / dv
        Hx, Hy, Hz = Lx + Vx, Ly + Vy, Lz + Vz
        dh = np.sqrt(Hx * Hx + Hy * Hy + Hz * Hz)
        nl = NX * Lx + NY * Ly + NZ * Lz
        nv = NX * Vx + NY * Vy + NZ * Vz
        nh = np.clip((NX * Hx + NY * Hy + NZ * Hz) / dh, 0.0, 1.0)
        n = np.asarray(exponent, np.float64)
        out = np.asarray(strength, np.float64) * (n + 8.0) / 8.0 * nh**n
    return np.where((nl > 0) & (nv > 0) & np.isfinite(out), out, 0.0)


@dataclass(eq=False)
class SpecularView:
    """The glossy surface one camera sees: its eye and, per surface pixel of its view, the lobe.

    ``strength`` and ``exponent`` are ``(n,)`` float64 over the view's surface pixels (in
    :attr:`sim.precompute.View.surf` order; strength 0 where the surface is not glossy).
    """

    eye: np.ndarray
    strength: np.ndarray
    exponent: np.ndarray

    def reflectance(self, light, points, normals) -> np.ndarray:
        """(n,) float64 ``pi f_s`` of the view's surface pixels for a lens at ``light`` (:func:`reflectance`)."""
        return reflectance(light, self.eye, points, normals, self.strength, self.exponent)


def specular_view(gloss, kinds: np.ndarray, surface_kinds: dict[str, int], eye) -> SpecularView | None:
    """The :class:`SpecularView` of a camera at ``eye``, or None when the room has no gloss.

    Parameters
    ----------
    gloss : tuple of Gloss
        The scene's (``()``: None, the room renders as it always did).
    kinds : (n,) uint8
        What each surface pixel of the view sees (:data:`sim.precompute.TABLE`, ``MESH``).
    surface_kinds : dict
        Surface name -> its kind code, e.g. ``{"table": TABLE, "mesh": MESH}``.
    """
    if not gloss:
        return None
    strength = np.zeros(len(kinds), np.float64)
    exponent = np.ones(len(kinds), np.float64)
    for g in gloss:
        if not isinstance(g, Gloss):
            raise TypeError(f"not a Gloss: {g!r}")
        on = kinds == surface_kinds[g.surface]
        strength[on] = g.strength
        exponent[on] = g.exponent
    return SpecularView(np.asarray(eye, np.float64).copy(), strength, exponent)
