"""The ``blend`` job's options, each defined once (:mod:`coordinator.jobs.options`): the dataclass the
job receives, its validation, its command-line flag and the console form's help all come from the field.

Only the standard library and :mod:`coordinator.jobs.options` are imported, so the command that builds
its flags from this class starts quickly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

from coordinator.jobs.errors import JobError
from coordinator.jobs.options import option

__all__ = ["BlendOptions", "HEADROOM_MAX", "MAP_SCALE_MAX", "parse_headroom", "parse_map_scale"]

#: the coarsest blend maps (a texel of MAP_SCALE_MAX x MAP_SCALE_MAX projector pixels)
MAP_SCALE_MAX = 64

#: the largest headroom (as imaging.blending.solve.HEADROOM_MAX, without importing the numerics)
HEADROOM_MAX = 0.9

CAMERA = "camera and captures"
MEASURE = "what to measure"
BLEND = "the blend"


def _auto_or(value: Any, convert: Callable[[str], Any], valid: Callable[[Any], bool], refusal: str) -> Any:
    """"auto", or ``value`` (a number, or text that ``convert`` reads) when ``valid``; else a one-line
    :class:`JobError`: ``refusal`` followed by the value given."""
    if isinstance(value, str):
        text = value.strip().lower()
        if text == "auto":
            return "auto"
        try:
            value = convert(text)
        except ValueError:
            raise JobError(f"{refusal}, got {value!r}") from None
    if isinstance(value, bool) or not valid(value):
        raise JobError(f"{refusal}, got {value!r}")
    return value


def parse_headroom(value: Any) -> str | float:
    """"auto" or a fraction in 0..0.9; a one-line :class:`JobError` otherwise."""
    got = _auto_or(value, float, lambda v: isinstance(v, (int, float)) and math.isfinite(v)
                   and 0.0 <= float(v) <= HEADROOM_MAX, f"headroom must be 'auto' or a number in 0..{HEADROOM_MAX}")
    return got if got == "auto" else float(got)


def parse_map_scale(value: Any) -> str | int:
    """"auto" or an integer 1..MAP_SCALE_MAX; a one-line :class:`JobError` otherwise."""
    got = _auto_or(value, int, lambda v: isinstance(v, int) and 1 <= v <= MAP_SCALE_MAX,
                   f"map_scale must be 'auto' or an integer 1..{MAP_SCALE_MAX}")
    return got if got == "auto" else int(got)


@dataclass(frozen=True, kw_only=True)
class BlendOptions:
    """Measure each projector's light through the camera and blend the rig: per-pixel alpha (gain) and beta
    (black offset) maps that make the summed light even in luminance and colour."""

    slots: list[str] | None = option(None, group=MEASURE,
                                     help="projectors to blend (default: every connected one with a pose)")
    headroom: str | float = option(
        "auto", parse=parse_headroom, cli_type=str, metavar="auto|H", group=BLEND,
        help="light held in reserve so a lost projector can be covered: 'auto' keeps enough that losing any one "
             "projector is covered wherever others reach (about 1/N of the brightness on an N-fold overlap), "
             f"a fraction 0..{HEADROOM_MAX} keeps that share of every point's light; the result says what it costs")
    map_scale: str | int = option(
        "auto", parse=parse_map_scale, cli_type=str, metavar="auto|N", group=BLEND,
        help="blend maps at 1/N of each projector's resolution (one texture per node); auto: 4 on a planar rig, "
             "and on a mesh rig as fine as the camera grid resolves on the surface (the projector pixels one grid "
             "cell spans, 1 to 4), since a grazed surface's light changes faster than a coarse map can follow")
    smoothness: float = option(1.0, lo=0.01, hi=100.0, metavar="S", group=BLEND,
                               help="how far the target's log-luminance may change over the camera's diagonal: lower "
                                    "is flatter and darker, higher follows the projectors' light more closely")
    ramp: float = option(0.15, lo=0.01, hi=0.5, metavar="F", group=BLEND,
                         help="each projector's weight ramps to 0 over this fraction of its smaller side at its edges")
    grid_scale: int | None = option(None, lo=1, hi=64, metavar="N", group=MEASURE,
                                    help="the contributions' grid is the camera image reduced N times (default: "
                                         "about 400 grid pixels across)")
    blob_radius: float | None = option(None, lo=1.0, hi=200.0, metavar="PX", group=MEASURE,
                                       help="radius of each measured blob, camera pixels (default: from the camera's "
                                            "size)")
    blob_spacing: float | None = option(None, lo=4.0, hi=1000.0, metavar="PX", group=MEASURE,
                                        help="distance between blob sites, camera pixels (default: 2 radii plus a "
                                             "guard against the lens's blur)")
    samples: int = option(48, lo=8, hi=10000, metavar="N", group=MEASURE,
                          help="blob samples per projector; more cost captures (each capture samples every "
                               "projector at once)")
    degree: int = option(4, lo=0, hi=8, metavar="D", group=MEASURE,
                         help="degree of the smooth model of each projector's light (fall-off, hot spot)")
    camera: int = option(0, lo=0, hi=64, flag="--camera-index", metavar="I", group=CAMERA,
                         help="which calibrated camera to use")
    frames: int = option(1, lo=1, hi=64, metavar="F", group=CAMERA, help="captures averaged per pattern")
    max_exposure: float = option(16.0, lo=1.0, hi=256.0, metavar="X", group=CAMERA,
                                 help="the blobs are captured up to X times longer than the camera's exposure (one "
                                      "projector's blob is much darker than the whole rig's white), when the camera "
                                      "can change its exposure")
    experimental_mesh: bool = option(False, group=MEASURE,
                                     help="blend a mesh rig (3D poses) too: experimental (on the room's bust, where 3 "
                                          "or more projectors reach, the light's non-uniformity goes from 0.36 to "
                                          "0.027, against a target of 0.03)")
    settle_s: float = option(0.05, lo=0.0, hi=30.0, flag="--settle", metavar="S", group=CAMERA,
                             help="wait after every swap before capturing, seconds")

    def validate(self) -> None:
        if self.blob_radius is not None and self.blob_spacing is not None and self.blob_spacing < 2 * self.blob_radius + 2:
            raise JobError(f"blob_spacing {self.blob_spacing:g} must be at least 2 x blob_radius + 2 = "
                           f"{2 * self.blob_radius + 2:g} camera pixels, so that blobs never touch")
