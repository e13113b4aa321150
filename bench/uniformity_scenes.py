"""The rooms `shadowless bench uniformity` measures in, and how it says that a part cannot run.

* the table: the paper's 5x5 array over the table with uneven light (:mod:`sim.photometry`: a
  brightness and a white-point spread, a hot spot and vignetting on top of the lens's fall-off);
* the wall: three projectors side by side whose footprints overlap by 20 % of their width;
* the bust: the procedural bust with projectors on the walls around it.

Each builder raises :class:`Missing` naming what this build lacks (a room without uneven light,
without the wall's layout, ...) instead of measuring something else under the same name: the
benchmark then reports ``null`` for that part's figures with the note.
"""
from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass

from sim.room import Room
from sim.scene import reference_scene

__all__ = ["Missing", "Light", "table_room", "wall_room", "bust_walls_room", "require", "slots_of"]

class Missing(Exception):
    """A part of the benchmark cannot run in this build: the message names what is absent."""


def require(module: str, what: str, *, attribute: str | None = None):
    """Import ``module`` (and return ``attribute`` of it), or raise :class:`Missing` naming ``what``."""
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise Missing(f"{what} is not in this build ({exc.name} missing)") from None
    if attribute is None:
        return mod
    if not hasattr(mod, attribute):
        raise Missing(f"{what} is not in this build ({module}.{attribute} missing)")
    return getattr(mod, attribute)


@dataclass(frozen=True)
class Light:
    """The uneven light asked of a room (fractions): see :class:`sim.photometry.Photometry`."""

    brightness_spread: float = 0.15
    white_spread: float = 0.15
    hotspot: float = 0.15
    vignetting: float = 0.2

    def photometry(self):
        Photometry = require("sim.photometry", "the room's uneven light (sim/photometry.py)", attribute="Photometry")
        return Photometry(brightness_spread=self.brightness_spread, white_spread=self.white_spread,
                          hotspot=self.hotspot, vignetting=self.vignetting)

    def as_dict(self) -> dict:
        return {"brightness_spread": self.brightness_spread, "white_spread": self.white_spread,
                "hotspot": self.hotspot, "vignetting": self.vignetting}


def _accepts(fn, name: str) -> bool:
    return name in inspect.signature(fn).parameters


def table_room(light: Light, *, projector_scale: float, camera_scale: float, seed: int, noise: bool = True,
               surface: str = "table") -> Room:
    """The reference 5x5 room over the table (or the bust on it) with ``light``."""
    if not _accepts(reference_scene, "photometry"):
        raise Missing("the room's uneven light (reference_scene(photometry=...), sim/scene.py) is not in this build")
    scene = reference_scene(projector_scale=projector_scale, camera_scale=camera_scale, seed=seed, surface=surface,
                            photometry=light.photometry())
    return Room(scene, seed=seed, noise=noise)


def _layout_room(builder: str, what: str, light: Light, *, projector_scale: float, camera_scale: float, seed: int,
                 noise: bool) -> tuple[Room, str]:
    """A room from the sim's builder ``builder`` (:mod:`sim.rigs`), or :class:`Missing`."""
    fn = require("sim.rigs", what, attribute=builder)
    scene = fn(projector_scale=projector_scale, camera_scale=camera_scale, seed=seed, photometry=light.photometry())
    return Room(scene, seed=seed, noise=noise), f"sim.rigs.{builder}"


def wall_room(light: Light, *, projector_scale: float, camera_scale: float, seed: int,
              noise: bool = True) -> tuple[Room, str]:
    """Three projectors side by side, footprints overlapping by 20 % of their width; and where it came from."""
    return _layout_room("wall_scene", "the 3x1 wall with 20 % overlap", light, projector_scale=projector_scale,
                        camera_scale=camera_scale, seed=seed, noise=noise)


def bust_walls_room(light: Light, *, projector_scale: float, camera_scale: float, seed: int,
                    noise: bool = True) -> tuple[Room, str]:
    """The bust with projectors on the walls around it; and where it came from."""
    return _layout_room("bust_walls_scene", "the bust with projectors around it", light, projector_scale=projector_scale,
                        camera_scale=camera_scale, seed=seed, noise=noise)


def slots_of(name: str) -> list[str]:
    """A named subset of the 5x5 array (P25, P9W, ...; P9 is P9W) or the first N of it."""
    from bench.calibration import rig_slots
    from sim.scene import SUBSETS
    key = "P9W" if name == "P9" else name
    if key in SUBSETS:
        return list(SUBSETS[key])
    return rig_slots(int(name))
