"""An observer in the room: an eye at a chosen point, added to a scene as one more camera.

A person at the table sees a glossy surface's highlights where the lenses' reflections reach
their eye (:mod:`sim.specular`); the rig's camera, on the ceiling, sees others. The observer is a
pinhole camera at ``position`` looking at ``target``, its focal length fitted so that the table
(or, without a table, the mesh's bounding box) fills its image. It is appended to the scene's
cameras, so the room renders it like any camera (``room.render_linear(camera=index)``) and the
other cameras' captures do not change.

Example::

    scene = with_observer(reference_scene(), (0.0, -60.0, 900.0))
    observer = len(scene.cameras) - 1
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from sim.errors import LayoutError
from sim.geometry import Pinhole, intrinsics, look_at
from sim.scene import CameraSpec, Scene, auto_gain, fit_focal

__all__ = ["OBSERVER_SIZE", "with_observer", "parse_point"]

#: The observer's image, (width, height) pixels, unless told.
OBSERVER_SIZE = (480, 360)


def parse_point(text: str, *, what: str = "point") -> tuple[float, float, float]:
    """``"X,Y,Z"`` (mm) -> a tuple of three floats; ValueError in one line otherwise."""
    parts = str(text).split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what} {text!r} must be three numbers X,Y,Z in mm, e.g. 0,-60,900")
    return values  # type: ignore[return-value]


def with_observer(scene: Scene, position, *, target=(0.0, 0.0, 0.0), size: tuple[int, int] = OBSERVER_SIZE,
                  up=(0.0, 1.0, 0.0), name: str = "observer", margin: float = 0.05) -> Scene:
    """``scene`` with an observer camera appended (the last camera).

    Parameters
    ----------
    position, target : (3,) float, mm
        Where the eye is and the point it looks at.
    size : (int, int)
        The observer's image (width, height), pixels.
    up : (3,) float
        The world direction towards the top of the image (default +y: the far side of the table
        for an eye at its near, -y, edge).
    margin : float
        Share of the half-image left around the table.

    Raises
    ------
    LayoutError
        The eye is on its target, or looks along ``up``.
    """
    eye = np.asarray(position, np.float64).reshape(3)
    aim = np.asarray(target, np.float64).reshape(3)
    w, h = (int(v) for v in size)
    if w < 8 or h < 8:
        raise LayoutError(f"the observer's image must be at least 8 x 8 pixels, got {w} x {h}")
    look = aim - eye
    if np.linalg.norm(look) < 1.0:
        raise LayoutError(f"the observer at {eye.tolist()} mm looks at its own position; give a target at least 1 mm away")
    if np.linalg.norm(np.cross(look / np.linalg.norm(look), np.asarray(up, np.float64))) < 1e-6:
        raise LayoutError(f"the observer looks along its up direction {list(up)}; give another up")
    if scene.table is not None:
        tw, th = scene.table.size
        seen = np.array([[sx * tw / 2, sy * th / 2, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
        albedo = scene.table.albedo
    else:
        lo, hi = scene.mesh.bounds
        seen = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        albedo = scene.mesh_albedo
    focal = fit_focal([eye], aim, up, (w, h), seen, margin=margin)
    R, t = look_at(eye, aim, up=up)
    pinhole = Pinhole(intrinsics((w, h), focal=focal), R, t, (w, h))
    try:
        gain = auto_gain(scene.projectors, pinhole, albedo=albedo)
    except LayoutError:  # no powered projector lights the point it looks at: the rig camera's gain
        gain = scene.cameras[0].gain
    return replace(scene, cameras=scene.cameras + (CameraSpec(name, pinhole, pinhole, gain),))
