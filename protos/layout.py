"""A layout file (TOML): a rig's geometry as planned, read once here for every package.

A layout names the table, the object on it, every projector (where it hangs, where it aims,
its resolution and focal length) and the cameras. ``shadowless plan`` writes one; the room
builds its scene from it (``shadowless room --layout``, :func:`sim.scene.load_layout`, which
adds the photometry: responses, peaks, apertures), and the coordinator a rig directory with
one slot per projector and each slot's planned pose (``shadowless rig init DIR --layout``).
The schema (millimetres; every key but ``position`` has a default) is documented with
:func:`sim.scene.load_layout`; what both sides need of it is parsed and checked here, once. The
photometry a layout may carry (a ``[photometry]`` section, a projector's ``white`` or ``hotspot``)
is the room's alone: it is passed through here and read by :mod:`sim.photometry`.

Only numpy and tomllib: the devices are built with :mod:`protos.spaces`' conventions.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from protos.spaces import intrinsics, look_at

__all__ = ["LayoutFileError", "TableSpec", "MeshSpec", "DeviceSpec", "Layout", "read_layout", "parse_layout",
           "PROJECTOR_NATIVE", "CAMERA_NATIVE", "TABLE_SIZE"]

#: Native resolutions of the reference devices (a layout's defaults).
PROJECTOR_NATIVE = (1280, 800)
CAMERA_NATIVE = (2592, 1944)
TABLE_SIZE = (1200.0, 600.0)

_TOP_LEVEL = {"name", "table", "mesh", "projector", "camera", "photometry"}


class LayoutFileError(ValueError):
    """A layout file cannot be read or is malformed; the message names the file and the entry."""


@dataclass(frozen=True)
class TableSpec:
    """The table: the plane z = 0, ``size`` (w, h) mm centred on the world origin."""

    size: tuple[float, float]
    albedo: float = 0.85


@dataclass(frozen=True)
class MeshSpec:
    """The object: a builtin mesh by name or a mesh file, placed by ``x -> scale * Rz(yaw) x + position``."""

    builtin: str | None = None
    path: Path | None = None
    albedo: float = 0.8
    yaw_deg: float = 0.0
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0
    placed: bool = False          # the layout moves the mesh (position, yaw_deg or scale given)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) float64: the yaw, counter-clockwise about +z."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def place(self, vertices: np.ndarray) -> np.ndarray:
        """(V, 3) float64 world mm of the mesh's (V, 3) vertices (unchanged unless ``placed``)."""
        v = np.asarray(vertices, np.float64)
        if not self.placed:
            return v
        return (self.scale * v) @ self.rotation.T + np.asarray(self.position, np.float64)


@dataclass(frozen=True, eq=False)
class DeviceSpec:
    """A projector or camera as the layout places it: a pinhole ``x ~ K (R X + t)`` of ``size``.

    ``entry`` is the layout's table for the device, for the keys only the room reads (a
    projector's gamma, peak, aperture, ...).
    """

    name: str
    position: np.ndarray          # (3,) float64 mm
    target: np.ndarray            # (3,) float64 mm, the aim point
    up: np.ndarray                # (3,) float64, the world direction towards the image top
    size: tuple[int, int]
    K: np.ndarray                 # (3, 3) float64
    R: np.ndarray                 # (3, 3) float64 world -> device
    t: np.ndarray                 # (3,) float64
    entry: dict = field(default_factory=dict)

    @property
    def projection(self) -> np.ndarray:
        """(3, 4) float64 ``K [R | t]``: world mm -> pixels of ``size``."""
        return self.K @ np.hstack([self.R, self.t[:, None]])


@dataclass(frozen=True, eq=False)
class Layout:
    """A parsed layout. ``photometry`` is the file's ``[photometry]`` table as written (uneven light:
    brightness and white-point spread, hot spot, vignetting), which only the room reads and checks
    (:mod:`sim.photometry`); empty when the file has none."""

    name: str
    table: TableSpec | None
    mesh: MeshSpec | None
    projectors: tuple[DeviceSpec, ...]
    cameras: tuple[DeviceSpec, ...]
    path: Path | None = None
    photometry: dict = field(default_factory=dict)


def read_layout(path: str | Path) -> Layout:
    """Read and check the layout at ``path``; LayoutFileError names the file and the entry."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as exc:
        raise LayoutFileError(f"cannot read layout {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise LayoutFileError(f"layout {path} is not text: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise LayoutFileError(f"layout {path} is not valid TOML: {exc}") from None
    try:
        return parse_layout(doc, base=path.parent, path=path)
    except LayoutFileError as exc:
        raise LayoutFileError(f"layout {path}: {exc}") from None
    except (TypeError, ValueError, KeyError) as exc:
        raise LayoutFileError(f"layout {path}: {exc}") from None


def _vec(entry: dict, key: str, n: int, default=None, *, where: str) -> np.ndarray:
    if key not in entry:
        if default is None:
            raise LayoutFileError(f"{where} needs {key!r}")
        return np.asarray(default, np.float64)
    val = np.asarray(entry[key], np.float64).reshape(-1)
    if val.shape != (n,) or not np.all(np.isfinite(val)):
        raise LayoutFileError(f"{where}: {key!r} must be {n} finite numbers, got {entry[key]!r}")
    return val


def _table(entries: object, what: str) -> list[dict]:
    if not isinstance(entries, list) or not entries:
        raise LayoutFileError(f"needs at least one [[{what}]]")
    if not all(isinstance(e, dict) for e in entries):
        raise LayoutFileError(f"every [[{what}]] must be a table")
    return entries


def _device(e: dict, *, name: str, where: str, native: tuple[int, int], focal_of) -> DeviceSpec:
    pos = _vec(e, "position", 3, where=where)
    target = _vec(e, "target", 3, (0, 0, 0), where=where)
    up = _vec(e, "up", 3, (0, 1, 0), where=where)
    res = tuple(int(v) for v in _vec(e, "resolution", 2, native, where=where))
    if min(res) <= 0:
        raise LayoutFileError(f"{where}: 'resolution' must be positive, got {list(res)}")
    principal = tuple(_vec(e, "principal", 2, ((res[0] - 1) / 2, (res[1] - 1) / 2), where=where))
    K = intrinsics(res, focal=focal_of(e, res), principal=principal)
    R, t = look_at(pos, target, up=up)
    return DeviceSpec(name, pos, target, up, res, K, R, t, dict(e))


def _projector_focal(e: dict, res: tuple[int, int]) -> float:
    if "focal_px" in e:
        return float(e["focal_px"])
    if "throw_ratio" in e:
        return float(e["throw_ratio"]) * res[0]
    return 0.98 * res[0]


def parse_layout(doc: dict, *, base: Path, path: Path | None = None) -> Layout:
    """A parsed layout document (``tomllib`` output) as a :class:`Layout`; mesh paths are taken
    relative to ``base``. LayoutFileError (or ValueError/TypeError from a malformed value) names
    the entry."""
    unknown = set(doc) - _TOP_LEVEL
    if unknown:
        raise LayoutFileError(f"unknown top-level keys {sorted(unknown)}; expected {sorted(_TOP_LEVEL)}")
    table = None
    if "table" in doc:
        t = doc["table"]
        table = TableSpec(tuple(float(v) for v in _vec(t, "size", 2, TABLE_SIZE, where="[table]")), float(t.get("albedo", 0.85)))
        if min(table.size) <= 0:
            raise LayoutFileError(f"[table]: 'size' must be positive, got {list(table.size)}")
    mesh = None
    if "mesh" in doc:
        m = doc["mesh"]
        if "builtin" in m:
            if m["builtin"] != "bust":
                raise LayoutFileError(f"[mesh]: unknown builtin {m['builtin']!r}; the builtin mesh is 'bust'")
            source: dict = {"builtin": "bust"}
        elif "path" in m:
            p = Path(str(m["path"]))
            source = {"path": p if p.is_absolute() else base / p}
        else:
            raise LayoutFileError("[mesh] needs 'builtin' or 'path'")
        mesh = MeshSpec(**source, albedo=float(m.get("albedo", 0.8)), yaw_deg=float(m.get("yaw_deg", 0.0)),
                        position=tuple(float(v) for v in _vec(m, "position", 3, (0, 0, 0), where="[mesh]")),
                        scale=float(m.get("scale", 1.0)), placed=any(k in m for k in ("position", "yaw_deg", "scale")))
    projectors = []
    for i, e in enumerate(_table(doc.get("projector", []), "projector")):
        slot = str(e.get("slot", f"p{i}"))
        projectors.append(_device(e, name=slot, where=f"[[projector]] #{i + 1} ({slot})", native=PROJECTOR_NATIVE,
                                  focal_of=_projector_focal))
    cameras = []
    for i, e in enumerate(_table(doc.get("camera", []), "camera")):
        cameras.append(_device(e, name=str(e.get("name", f"camera{i}")), where=f"[[camera]] #{i + 1}", native=CAMERA_NATIVE,
                               focal_of=lambda e, res: float(e.get("focal_px", 1.02 * res[0]))))
    photometry = doc.get("photometry", {})
    if not isinstance(photometry, dict):
        raise LayoutFileError("[photometry] must be a table")
    return Layout(str(doc.get("name", "room")), table, mesh, tuple(projectors), tuple(cameras), path, dict(photometry))
