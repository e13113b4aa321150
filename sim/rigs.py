"""Rigs whose projectors only partly overlap: a wall of projectors side by side, and projectors
on the walls around the bust. Each is a layout document (what a layout file holds,
:mod:`protos.layout`), a scene built from it, and a file shipped in ``sim/layouts/``.

* :func:`wall_layout` / :func:`wall_scene`: ``columns`` projectors in a row, each 1 m above a long
  planar surface (the room's table: a wall seen from the front is the same plane), aimed straight
  at it, their footprints 500 mm wide and overlapping their neighbours' by ``overlap`` of that
  width; one camera sees the whole surface. Slots ``r0c0``, ``r0c1``, ... from left (-x) to right.
  The surface is the footprints' union less 20 mm on every side, so every point of it is lit.
  The camera's gain is stated (:data:`WALL_CAMERA_GAIN`): where two footprints overlap the light
  doubles, and the automatic exposure would count projectors that do not reach the camera's axis.
* :func:`bust_walls_layout` / :func:`bust_walls_scene`: ``count`` projectors on the walls around
  the bust (1.3 m from its axis, 0.9 m up, evenly spaced, the first in front of its face), each
  aimed at the bust's middle and framing it, so each lights one side and its neighbours share
  the flanks; the table around it, and the reference rig's three cameras (their exposure 0.8 of
  the automatic one, which leaves room for a spread and a hot spot).

One call builds any of these rooms, or the reference rig, with or without uneven light:
:func:`scene` in this process, :func:`room_argv` as the arguments of a ``shadowless room``
process that serves the very same room (:data:`ROOMS` names them; :data:`BENCH_LIGHT` is the
uneven light of issue 37's benchmark).

Shipped files (:func:`layout_path`): ``wall-3x1.toml`` (3 columns, 20 % overlap) and
``bust-walls.toml`` (6 projectors), exactly what the builders give by default; use them with
``shadowless room --layout FILE`` (or the bare name, ``--layout wall-3x1``) and
``shadowless rig init DIR --layout FILE``. Uneven light (``--brightness-spread`` ..., a layout's
``[photometry]``) is :mod:`sim.photometry`'s.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from protos.layout import CAMERA_NATIVE, PROJECTOR_NATIVE, parse_layout
from sim.photometry import Photometry
from sim.scene import RING_CAMERAS, Scene, fit_focal, reference_scene, scene_from_layout

__all__ = ["LAYOUTS_DIR", "LAYOUTS", "ROOMS", "BENCH_LIGHT", "layout_path", "wall_layout", "wall_scene", "bust_walls_layout",
           "bust_walls_scene", "scene", "room_argv", "layout_toml"]

#: where the shipped layout files are
LAYOUTS_DIR = Path(__file__).parent / "layouts"

#: the shipped layouts by name
LAYOUTS = {"wall-3x1": "wall-3x1.toml", "bust-walls": "bust-walls.toml"}

#: a wall projector's distance to the surface and its footprint's width, mm
WALL_DISTANCE_MM = 1000.0
WALL_FOOTPRINT_MM = 500.0

#: the camera above the wall's centre, mm
WALL_CAMERA_HEIGHT_MM = 1400.0

#: the wall camera's gain: one projector alone gives about 0.4 of full scale (0.45 x albedo 0.85 x
#: irradiance about 1 at 1 m), two where they overlap about 0.8, with room for a spread and a hot spot
WALL_CAMERA_GAIN = 0.45


#: the rooms :func:`scene` and :func:`room_argv` build: the reference 5 x 5 rig over the table or the
#: bust, the 3 x 1 wall, the projectors on the walls around the bust
ROOMS = ("table", "bust", "wall", "bust-walls")

#: issue 37's uneven light: units +-15 % in brightness and in white point, a 15 % hot spot, 20 % vignetting
BENCH_LIGHT = Photometry(brightness_spread=0.15, white_spread=0.15, hotspot=0.15, vignetting=0.2)


def layout_path(name: str) -> Path:
    """The shipped layout file ``name`` (``wall-3x1``, ``bust-walls``); ValueError names the choices."""
    if name not in LAYOUTS:
        raise ValueError(f"no shipped layout {name!r}; there are {', '.join(LAYOUTS)}")
    return LAYOUTS_DIR / LAYOUTS[name]


def _r(v, nd: int = 3):
    """Rounded floats (so the shipped files read well and equal the builders' documents)."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_r(x, nd) for x in np.asarray(v, np.float64).tolist()]
    return round(float(v), nd)


def wall_layout(columns: int = 3, overlap: float = 0.2) -> dict:
    """The layout document of ``columns`` projectors side by side over a long surface.

    Parameters
    ----------
    columns : int
        Projectors in the row (1 to 8).
    overlap : float
        Fraction of a footprint's width it shares with each neighbour (0 to 0.5).

    Returns
    -------
    dict: a layout document (:func:`protos.layout.parse_layout` reads it).
    """
    if isinstance(columns, bool) or not isinstance(columns, int) or not 1 <= columns <= 8:
        raise ValueError(f"columns must be an integer 1..8, got {columns!r}")
    if not 0.0 <= float(overlap) <= 0.5:
        raise ValueError(f"overlap must be a fraction 0..0.5 of a footprint's width, got {overlap!r}")
    fw = WALL_FOOTPRINT_MM
    w, h = PROJECTOR_NATIVE
    fh = fw * h / w
    step = fw * (1.0 - overlap)
    width = fw + step * (columns - 1)
    surface = (width - 40.0, fh - 40.0)
    focal = w * WALL_DISTANCE_MM / fw                  # the footprint's width at the distance
    projectors = []
    for c in range(columns):
        x = (c - (columns - 1) / 2) * step
        projectors.append({"slot": f"r0c{c}", "position": _r([x, 0.0, WALL_DISTANCE_MM]), "target": _r([x, 0.0, 0.0]),
                           "up": [0.0, 1.0, 0.0], "resolution": [w, h], "focal_px": _r(focal)})
    cam_pos = np.array([0.0, -100.0, WALL_CAMERA_HEIGHT_MM])
    corners = np.array([[sx * surface[0] / 2, sy * surface[1] / 2, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    cam_focal = fit_focal([cam_pos], np.zeros(3), (0.0, 1.0, 0.0), CAMERA_NATIVE, corners, margin=0.04)
    camera = {"name": "front", "position": _r(cam_pos), "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
              "resolution": list(CAMERA_NATIVE), "focal_px": _r(cam_focal, 1), "gain": WALL_CAMERA_GAIN}
    return {"name": f"wall-{columns}x1-overlap-{round(overlap * 100)}",
            "table": {"size": _r(surface, 1), "albedo": 0.85},
            "projector": projectors, "camera": [camera]}


def bust_walls_layout(count: int = 6) -> dict:
    """The layout document of ``count`` projectors on the walls around the bust (3 to 12).

    Returns
    -------
    dict: a layout document (:func:`protos.layout.parse_layout` reads it).
    """
    if isinstance(count, bool) or not isinstance(count, int) or not 3 <= count <= 12:
        raise ValueError(f"count must be an integer 3..12, got {count!r}")
    radius, height = 1300.0, 900.0
    middle = np.array([0.0, 0.0, 300.0])
    up = (0.0, 0.0, 1.0)
    # the bust (about 300 x 250 x 600 mm) and a margin around it
    box = np.array([[x, y, z] for x in (-200.0, 200.0) for y in (-180.0, 180.0) for z in (-20.0, 640.0)])
    positions = [np.array([radius * math.cos(a), radius * math.sin(a), height])
                 for a in (math.pi / 2 + 2 * math.pi * k / count for k in range(count))]
    focal = fit_focal(positions, middle, up, PROJECTOR_NATIVE, box, margin=0.02)
    projectors = [{"slot": f"w{k}", "position": _r(p), "target": _r(middle), "up": list(up),
                   "resolution": list(PROJECTOR_NATIVE), "focal_px": _r(focal)} for k, p in enumerate(positions)]
    cams = [("ceiling", np.array([0.0, -125.0, 1400.0]), np.zeros(3), (0.0, 1.0, 0.0))]
    cams += [(name, np.asarray(pos, np.float64), np.array([0.0, 0.0, 250.0]), (0.0, 0.0, 1.0)) for name, pos in RING_CAMERAS]
    seen = np.array([[x, y, z] for x in (-160, 160) for y in (-140, 140) for z in (0, 600)]
                    + [[x, y, 0.0] for x in (-450, 450) for y in (-250, 250)], np.float64)
    cameras = []
    for name, pos, target, cam_up in cams:
        f = fit_focal([pos], target, cam_up, CAMERA_NATIVE, seen, margin=0.05)
        cameras.append({"name": name, "position": _r(pos), "target": _r(target), "up": list(cam_up),
                        "resolution": list(CAMERA_NATIVE), "focal_px": _r(f, 1), "exposure": 0.8})
    return {"name": f"bust-walls-{count}", "table": {"size": [1200.0, 600.0], "albedo": 0.85},
            "mesh": {"builtin": "bust", "albedo": 0.8}, "projector": projectors, "camera": cameras}


def _scene(doc: dict, *, projector_scale: float, camera_scale: float, seed: int, photometry: Photometry | dict | None) -> Scene:
    layout = parse_layout(doc, base=LAYOUTS_DIR)
    return scene_from_layout(layout, projector_scale=projector_scale, camera_scale=camera_scale, seed=seed, photometry=photometry)


def wall_scene(columns: int = 3, overlap: float = 0.2, *, projector_scale: float = 0.25, camera_scale: float = 0.25,
               seed: int = 0, photometry: Photometry | dict | None = None) -> Scene:
    """The room of :func:`wall_layout` (resolutions, seed and photometry as :func:`sim.scene.load_layout`)."""
    return _scene(wall_layout(columns, overlap), projector_scale=projector_scale, camera_scale=camera_scale, seed=seed,
                  photometry=photometry)


def bust_walls_scene(count: int = 6, *, projector_scale: float = 0.25, camera_scale: float = 0.25, seed: int = 0,
                     photometry: Photometry | dict | None = None) -> Scene:
    """The room of :func:`bust_walls_layout` (resolutions, seed and photometry as :func:`sim.scene.load_layout`)."""
    return _scene(bust_walls_layout(count), projector_scale=projector_scale, camera_scale=camera_scale, seed=seed,
                  photometry=photometry)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def layout_toml(doc: dict, *, header: str = "") -> str:
    """A layout document as TOML text (scalars first, then tables, then arrays of tables)."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    if lines:
        lines.append("")
    for k, v in doc.items():
        if not isinstance(v, (dict, list)) or (isinstance(v, list) and not (v and isinstance(v[0], dict))):
            lines.append(f"{k} = {_toml_value(v)}")
    lines.append("")
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f"[{k}]")
            lines += [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
            lines.append("")
    for k, v in doc.items():
        if isinstance(v, list) and v and isinstance(v[0], dict):
            for entry in v:
                lines.append(f"[[{k}]]")
                lines += [f"{kk} = {_toml_value(vv)}" for kk, vv in entry.items()]
                lines.append("")
    return "\n".join(lines)


def scene(name: str, *, photometry: Photometry | None = None, projector_scale: float = 0.25, camera_scale: float = 0.25,
          seed: int = 0, cameras: int = 1) -> Scene:
    """One of :data:`ROOMS` as a scene, with ``photometry`` (none by default).

    ``"table"`` and ``"bust"`` are :func:`sim.scene.reference_scene` (``cameras`` 1 or 3),
    ``"wall"`` the shipped ``wall-3x1`` (:func:`wall_scene`), ``"bust-walls"`` the shipped
    ``bust-walls`` (:func:`bust_walls_scene`). ``Room(scene(...), seed=seed)`` is the room a
    ``shadowless room`` process started with :func:`room_argv` of the same arguments serves.
    """
    if name in ("table", "bust"):
        return reference_scene(projector_scale, camera_scale, name, seed, cameras=cameras, photometry=photometry)
    if name == "wall":
        return wall_scene(projector_scale=projector_scale, camera_scale=camera_scale, seed=seed, photometry=photometry)
    if name == "bust-walls":
        return bust_walls_scene(projector_scale=projector_scale, camera_scale=camera_scale, seed=seed, photometry=photometry)
    raise ValueError(f"no room {name!r}; there are {', '.join(ROOMS)}")


def room_argv(name: str, *, photometry: Photometry | None = None, projector_scale: float = 0.25, camera_scale: float = 0.25,
              seed: int = 0, cameras: int = 1) -> list[str]:
    """The arguments after ``shadowless room`` that serve :func:`scene` of the same arguments.

    Add ``--port``, ``--no-noise`` and the like as needed.
    """
    if name not in ROOMS:
        raise ValueError(f"no room {name!r}; there are {', '.join(ROOMS)}")
    argv = ["--projector-scale", repr(float(projector_scale)), "--camera-scale", repr(float(camera_scale)), "--seed", str(int(seed))]
    if name in ("table", "bust"):
        argv += ["--surface", name, "--cameras", str(int(cameras))]
    else:
        argv += ["--layout", str(layout_path("wall-3x1" if name == "wall" else "bust-walls"))]
    if photometry is not None:
        for key in ("brightness_spread", "white_spread", "hotspot", "hotspot_width", "vignetting"):
            argv += ["--" + key.replace("_", "-"), repr(float(getattr(photometry, key)))]
    return argv
