"""Known points and landmarks: 3D points (mm) and where a camera sees them (px).

An operator writes such a file by clicking marks in a camera image (table
corners, tape marks at measured positions, distinctive features of a mesh);
the virtual room can write one from its ground truth with click noise. The
format is JSON::

    {
      "frame": "world",                    # or "model": points in the mesh's own coordinates
      "points": [
        {"name": "table -x+y", "xyz": [-600, 300, 0], "camera": 0, "pixel": [14.2, 33.9]},
        {"name": "tape 1", "xy": [0, 0], "pixel": [323.5, 242.4]},   # "xy": on the table (z = 0)
        ...
      ]
    }

``camera`` defaults to 0; ``pixel`` follows OpenCV (pixel centres at
integers). The rig file may list table points inline instead::

    [calibration]
    table_points = [[-600, 300, 14.2, 33.9], ...]   # x_mm, y_mm, u_px, v_px (camera 0)
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imaging.calibration.errors import CalibrationError
from protos.store import atomic_write_json

FRAMES = ("world", "model")


@dataclass(frozen=True, eq=False)
class PointSet:
    """Points of one frame seen by one camera.

    Attributes
    ----------
    frame : "world" or "model"
    camera : int
    names : tuple of str
    xyz : (N, 3) float64 mm
    pixels : (N, 2) float64 camera px
    """

    frame: str
    camera: int
    names: tuple[str, ...]
    xyz: np.ndarray
    pixels: np.ndarray

    def __len__(self) -> int:
        return len(self.names)

    @property
    def planar(self) -> bool:
        """All points on the table plane z = 0 (world frame)."""
        return self.frame == "world" and bool(np.all(np.abs(self.xyz[:, 2]) < 1e-9))


def _vector(value, n: int, where: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise CalibrationError(f"{where}: expected {n} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise CalibrationError(f"{where}: expected {n} finite numbers, got {value!r}")
        out.append(float(v))
    return out


def parse_points(doc: object, *, source: str) -> list[PointSet]:
    """Validate a points document (see the module docstring); one PointSet per camera."""
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source}: must be a JSON object with a 'points' list")
    frame = doc.get("frame", "world")
    if frame not in FRAMES:
        raise CalibrationError(f"{source}: frame must be 'world' or 'model', got {frame!r}")
    entries = doc.get("points")
    if not isinstance(entries, list) or not entries:
        raise CalibrationError(f"{source}: needs a non-empty 'points' list")
    by_camera: dict[int, list[tuple[str, list[float], list[float]]]] = {}
    for i, e in enumerate(entries):
        where = f"{source}: point #{i + 1}"
        if not isinstance(e, dict):
            raise CalibrationError(f"{where} must be an object with xyz (or xy) and pixel")
        name = str(e.get("name", f"p{i + 1}"))
        where = f"{source}: point {name!r}"
        if "xyz" in e:
            xyz = _vector(e["xyz"], 3, f"{where} xyz")
        elif "xy" in e:
            xyz = _vector(e["xy"], 2, f"{where} xy") + [0.0]
        else:
            raise CalibrationError(f"{where} needs xyz (mm) or xy (mm on the table)")
        if "pixel" not in e:
            raise CalibrationError(f"{where} needs pixel [u, v] (camera px)")
        px = _vector(e["pixel"], 2, f"{where} pixel")
        cam = e.get("camera", 0)
        if isinstance(cam, bool) or not isinstance(cam, int) or cam < 0:
            raise CalibrationError(f"{where}: camera must be a camera number (0, 1, ...), got {cam!r}")
        by_camera.setdefault(cam, []).append((name, xyz, px))
    out = []
    for cam in sorted(by_camera):
        rows = by_camera[cam]
        out.append(PointSet(frame, cam, tuple(r[0] for r in rows), np.array([r[1] for r in rows], np.float64),
                            np.array([r[2] for r in rows], np.float64)))
    return out


def read_points(path: str | Path) -> list[PointSet]:
    """Read a points file; raise :class:`CalibrationError` naming the file and the bad entry."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise CalibrationError(f"cannot read points file {path}: {exc.strerror or exc}") from exc
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"points file {path} is not valid JSON: {exc}") from exc
    return parse_points(doc, source=str(path))


def inline_table_points(rows: object, *, source: str) -> list[PointSet]:
    """``[[x_mm, y_mm, u_px, v_px], ...]`` (camera 0, table plane) from the rig file."""
    if not isinstance(rows, list) or not rows:
        raise CalibrationError(f"{source}: table_points must be a list of [x_mm, y_mm, u_px, v_px]")
    doc = {"frame": "world", "points": []}
    for i, r in enumerate(rows):
        v = _vector(r, 4, f"{source}: table_points #{i + 1} ([x_mm, y_mm, u_px, v_px])")
        doc["points"].append({"name": f"table point {i + 1}", "xy": v[:2], "pixel": v[2:]})
    return parse_points(doc, source=source)


def write_points(path: str | Path, sets: list[PointSet]) -> None:
    """Write point sets (one frame) as a points file, atomically."""
    if not sets:
        raise ValueError("nothing to write")
    frames = {s.frame for s in sets}
    if len(frames) != 1:
        raise ValueError(f"one file holds one frame, got {sorted(frames)}")
    pts = []
    for s in sets:
        for name, xyz, px in zip(s.names, s.xyz, s.pixels):
            pts.append({"name": name, "xyz": [float(v) for v in xyz], "camera": s.camera, "pixel": [float(v) for v in px]})
    atomic_write_json(path, {"frame": frames.pop(), "points": pts})
