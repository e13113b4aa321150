"""Uneven light: how projectors of one rig differ in brightness and white point, and how each
one's light varies across its image (a hot spot, vignetting beyond the lens's cos fall-off).

Every effect here is off by default, and a room built without them is exactly the room it was
before they existed: nothing is multiplied, no random number is drawn.

The model, per projector, at projector pixel coordinate ``(u, v)`` and channel ``c``::

    light = peak * white[c] * lamp[c] * profile(u, v) * response_c(value)    (then irradiance, albedo)

* ``peak`` (:attr:`sim.scene.ProjectorSpec.peak`): the unit's brightness. A **brightness spread**
  ``s`` multiplies it by a factor drawn uniformly in ``1 +- s``.
* ``white`` (:attr:`sim.scene.ProjectorSpec.white`): per-channel gains, the unit's white point. A
  **white spread** ``s`` draws each channel's gain uniformly in ``1 +- s``.
* ``lamp`` (:meth:`sim.room.Room.set_lamp`): the lamp now, per channel, 1 = as new, 0 = dead. It
  changes while the projector keeps showing its frames (its node stays live); it scales the
  black level too, which is the lamp's light leaking through.
* ``profile`` (:class:`Profile`): a smooth function of the projector coordinate, a hot spot
  (a Gaussian bump) times vignetting (a quadratic loss towards the corners).

The spreads are drawn per projector from the room's seed and the slot's name (not from the order
of the projectors, and not from the generator that places the units), so the same seed gives the
same units, and a room's geometry does not change when its photometry does.

Coordinates of a profile: ``x = 2 (u + 0.5) / w - 1`` and ``y = 2 (v + 0.5) / h - 1`` run from
-1 to 1 across the image (left to right, top to bottom) whatever its resolution; distances are
measured with the image's aspect, in units of the half-diagonal, so a corner is at distance 1
from the centre.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, fields, replace

import numpy as np

__all__ = ["Profile", "Photometry", "PHOTOMETRY_KEYS", "PROJECTOR_KEYS", "parse_photometry", "projector_photometry",
           "spread_draw", "apply_photometry", "check_lamp"]


@dataclass(frozen=True)
class Profile:
    """A projector's light across its image: ``(1 + hotspot * exp(-d^2 / (2 width^2))) * (1 - vignetting * r^2)``.

    ``r`` is the distance from the image centre and ``d`` that from ``hotspot_center``, both in
    units of the half-diagonal (module docstring).

    Attributes
    ----------
    hotspot : float
        Extra light at the hot spot's centre: 0.2 = 20 % brighter there (0 = none, at most 4).
    hotspot_width : float
        The hot spot's standard deviation, in half-diagonals (0.05 to 4; default 0.35).
    hotspot_center : (float, float)
        Its centre in normalised image coordinates, (0, 0) = the image centre, each in -1..1.
    vignetting : float
        Light lost at the corners: 0.3 = the corners get 30 % less (0 = none, below 1).
    """

    hotspot: float = 0.0
    hotspot_width: float = 0.35
    hotspot_center: tuple[float, float] = (0.0, 0.0)
    vignetting: float = 0.0

    def __post_init__(self) -> None:
        c = tuple(float(v) for v in np.asarray(self.hotspot_center, np.float64).reshape(-1))
        if len(c) != 2 or not all(math.isfinite(v) and -1.0 <= v <= 1.0 for v in c):
            raise ValueError(f"hotspot_center must be two numbers in -1..1 (the image centre is 0, 0), got {self.hotspot_center!r}")
        object.__setattr__(self, "hotspot_center", c)
        for name, lo, hi, lo_open, hi_open in (("hotspot", 0.0, 4.0, False, False), ("hotspot_width", 0.05, 4.0, False, False),
                                               ("vignetting", 0.0, 1.0, False, True)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(float(v)) \
                    or float(v) < lo or float(v) > hi or (hi_open and float(v) >= hi):
                raise ValueError(f"{name} must be a number in {lo:g}..{hi:g}{' (not ' + format(hi, 'g') + ')' if hi_open else ''}, got {v!r}")
            object.__setattr__(self, name, float(v))

    @property
    def identity(self) -> bool:
        """True when the profile is 1 everywhere (no hot spot, no vignetting)."""
        return self.hotspot == 0.0 and self.vignetting == 0.0

    def factor(self, u: np.ndarray, v: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """The profile at projector coordinates ``(u, v)`` of an image of ``size`` (w, h).

        Parameters
        ----------
        u, v : (...) float arrays, projector pixels (pixel centres at integers)
        size : (int, int)

        Returns
        -------
        (...) float64, positive
        """
        w, h = size
        x = 2.0 * (np.asarray(u, np.float64) + 0.5) / w - 1.0
        y = 2.0 * (np.asarray(v, np.float64) + 0.5) / h - 1.0
        diag2 = float(w * w + h * h)
        out = np.ones(np.broadcast_shapes(x.shape, y.shape))
        if self.vignetting:
            out = out * (1.0 - self.vignetting * np.clip((x * x * w * w + y * y * h * h) / diag2, 0.0, 1.0))
        if self.hotspot:
            cx, cy = self.hotspot_center
            d2 = ((x - cx) ** 2 * w * w + (y - cy) ** 2 * h * h) / diag2
            out = out * (1.0 + self.hotspot * np.exp(-0.5 * d2 / (self.hotspot_width ** 2)))
        return out

    def image(self, size: tuple[int, int]) -> np.ndarray:
        """(h, w) float64: the profile at every pixel centre of an image of ``size`` (w, h)."""
        w, h = size
        return self.factor(np.arange(w, dtype=np.float64)[None, :], np.arange(h, dtype=np.float64)[:, None], size)


@dataclass(frozen=True)
class Photometry:
    """Rig-wide uneven light: what ``shadowless room --brightness-spread ...`` and a layout's
    ``[photometry]`` section set. All zero (the default) changes nothing.

    Attributes
    ----------
    brightness_spread : float
        Each projector's peak times a factor uniform in ``1 +- brightness_spread`` (0 to 0.9).
    white_spread : float
        Each channel's gain uniform in ``1 +- white_spread`` (0 to 0.9), per projector.
    hotspot, hotspot_width, vignetting : float
        Every projector's :class:`Profile` (a layout's projector may set its own).
    """

    brightness_spread: float = 0.0
    white_spread: float = 0.0
    hotspot: float = 0.0
    hotspot_width: float = 0.35
    vignetting: float = 0.0

    def __post_init__(self) -> None:
        for name in ("brightness_spread", "white_spread"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not 0.0 <= float(v) <= 0.9:
                raise ValueError(f"{name} must be a fraction in 0..0.9 (0.15 = +-15 %), got {v!r}")
            object.__setattr__(self, name, float(v))
        Profile(self.hotspot, self.hotspot_width, (0.0, 0.0), self.vignetting)   # checks the profile's values
        for name in ("hotspot", "hotspot_width", "vignetting"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def none(self) -> bool:
        """True when nothing is uneven (the default room)."""
        return self.brightness_spread == 0 and self.white_spread == 0 and self.hotspot == 0 and self.vignetting == 0

    @property
    def profile(self) -> Profile:
        return Profile(self.hotspot, self.hotspot_width, (0.0, 0.0), self.vignetting)

    def merged(self, **overrides) -> "Photometry":
        """This photometry with the given fields replaced (None values are ignored)."""
        return replace(self, **{k: v for k, v in overrides.items() if v is not None})


#: the keys of a layout's ``[photometry]`` section
PHOTOMETRY_KEYS = tuple(f.name for f in fields(Photometry))

#: the photometry keys a layout's ``[[projector]]`` may carry (beside gamma, black, peak, ...)
PROJECTOR_KEYS = ("white", "hotspot", "hotspot_width", "hotspot_center", "vignetting")


def parse_photometry(entry: dict | None, *, where: str = "[photometry]") -> Photometry:
    """A layout's ``[photometry]`` table as :class:`Photometry`; ValueError names the key."""
    if entry is None:
        return Photometry()
    if not isinstance(entry, dict):
        raise ValueError(f"{where} must be a table")
    unknown = set(entry) - set(PHOTOMETRY_KEYS)
    if unknown:
        raise ValueError(f"{where}: unknown keys {sorted(unknown)}; expected some of {list(PHOTOMETRY_KEYS)}")
    try:
        return Photometry(**entry)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def _gains(value, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, np.float64).reshape(-1) if not isinstance(value, bool) else np.array([np.nan])
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be one number or three (r, g, b), got {value!r}") from None
    if arr.shape == (1,):
        arr = np.repeat(arr, 3)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be one number or three (r, g, b), got {value!r}")
    return arr


def projector_photometry(entry: dict, rig: Photometry, *, where: str) -> tuple[np.ndarray | None, Profile | None]:
    """A layout projector's own white gains and profile (None: take the rig's).

    ``white`` is one gain or three (each 0.05 to 4); the profile keys replace the rig's one by one.
    """
    white = None
    if "white" in entry:
        white = _gains(entry["white"], f"{where}: 'white'")
        if np.any(white < 0.05) or np.any(white > 4.0):
            raise ValueError(f"{where}: 'white' gains must be in 0.05..4, got {entry['white']!r}")
    own = {k: entry[k] for k in ("hotspot", "hotspot_width", "hotspot_center", "vignetting") if k in entry}
    profile = None
    if own:
        base = rig.profile
        try:
            profile = Profile(**{"hotspot": base.hotspot, "hotspot_width": base.hotspot_width,
                                 "hotspot_center": base.hotspot_center, "vignetting": base.vignetting, **own})
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
    return white, profile


def spread_draw(seed: int, slot: str, photometry: Photometry) -> tuple[float, np.ndarray]:
    """The brightness factor and the (3,) white gains of unit ``slot`` under ``photometry``.

    Drawn from a generator of its own, seeded by ``seed`` and the slot's name: the same for the
    same seed and slot, whatever else the room holds.
    """
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(slot.encode()), 37])
    b, w = rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0, size=3)
    return 1.0 + photometry.brightness_spread * float(b), 1.0 + photometry.white_spread * w


def apply_photometry(projectors, photometry: Photometry, *, seed: int, own: dict | None = None,
                     explicit_peak: frozenset[str] = frozenset()):
    """The projectors (:class:`sim.scene.ProjectorSpec`) with ``photometry`` applied.

    Parameters
    ----------
    projectors : sequence of ProjectorSpec
    photometry : Photometry
    seed : int
        The room's seed (see :func:`spread_draw`).
    own : dict, optional
        slot -> (white or None, Profile or None): a layout projector's own values
        (:func:`projector_photometry`), which win over the rig's.
    explicit_peak : frozenset of str
        Slots whose peak the layout states: the brightness spread leaves them alone.

    Returns
    -------
    tuple of ProjectorSpec (the same objects when nothing applies to them)
    """
    own = own or {}
    out = []
    for p in projectors:
        white, profile = own.get(p.slot, (None, None))
        changes: dict = {}
        if photometry.brightness_spread or photometry.white_spread:
            factor, gains = spread_draw(seed, p.slot, photometry)
            if photometry.brightness_spread and p.slot not in explicit_peak:
                changes["peak"] = p.peak * factor
            if photometry.white_spread and white is None:
                white = gains
        if white is not None:
            changes["white"] = np.asarray(white, np.float64)
        if profile is None and not photometry.profile.identity:
            profile = photometry.profile
        if profile is not None and not profile.identity:
            changes["profile"] = profile
        out.append(replace(p, **changes) if changes else p)
    return tuple(out)


def check_lamp(gain) -> np.ndarray:
    """(3,) float64 lamp gains from one number or three, each in 0..1; ValueError otherwise."""
    try:
        arr = _gains(gain, "a lamp gain")
    except (TypeError, ValueError):
        raise ValueError(f"a lamp gain must be one number or three (r, g, b) in 0..1 (1 = as new, 0 = dead), got {gain!r}") from None
    if np.any(arr < 0) or np.any(arr > 1):
        raise ValueError(f"a lamp gain must be in 0..1 (1 = as new, 0 = dead), got {gain!r}")
    return arr
