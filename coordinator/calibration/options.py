"""The options of the ``calibrate`` and ``alignment`` jobs, each defined once.

:class:`CalibrateOptions` and :class:`AlignmentOptions` are the dataclasses the jobs
receive (:mod:`coordinator.jobs.options`): the coordinator validates a request's JSON
parameters against them, ``shadowless calibrate`` / ``shadowless alignment`` build their
flags from them, and their help texts document them.

A calibration option may also be set in rig.toml's ``[calibration]`` table::

    [calibration]
    mode = "sequential"
    table_points = [[-560, 260, 41.3, 37.9], ...]    # x_mm, y_mm, u_px, v_px (camera 0)

What a request gives wins over the table (:func:`with_rig_defaults`). Options that name
files or carry documents (known points, landmarks, a ChArUco board, a mesh, camera
intrinsics) are checked for their shape here and turned into data by :func:`resolve`
(relative paths against the rig directory, where rig.toml names them).

This module is what the command line imports: it needs neither OpenCV nor SciPy.
"""
from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from imaging.calibration.errors import CalibrationError
from imaging.calibration.board import DEFAULT_BOARD
from imaging.calibration.planar import CharucoSpec
from imaging.calibration.points import PointSet, inline_table_points, parse_points, read_points
from coordinator.jobs import JobError, option

__all__ = ["CalibrateOptions", "AlignmentOptions", "Inputs", "rig_defaults", "decide", "resolve"]

#: the board description in a rig directory that calibrate looks for on the table when it is given no
#: table points nor board (what `shadowless rig board RIG` writes)
BOARD_FILE = "board.json"

WHAT = "what to calibrate"
CAPTURES = "cameras and captures"


# ---------------------------------------------------------------------- shape checks (parse=)
def _path_or_document(what: str, *, rows: bool = False):
    """A file path (str), a document sent inline (dict; the CLI reads local files), or with
    ``rows`` an inline list of ``[x_mm, y_mm, u_px, v_px]``."""

    def check(value: Any) -> Any:
        if isinstance(value, str) and value:
            return value
        if isinstance(value, dict) or (rows and isinstance(value, list)):
            return value
        extra = ", a points document or a list of [x_mm, y_mm, u_px, v_px]" if rows else " or a points document"
        raise JobError(f"{what} must be a file path{extra}, got {value!r}")

    return check


def _board(value: Any) -> dict:
    if not isinstance(value, dict):
        raise JobError("charuco must be a table/object describing the board")
    return value


def _file_path(what: str):
    def check(value: Any) -> str:
        if not isinstance(value, str) or not value:
            raise JobError(f"{what} must be a file path")
        return value

    return check


def _intrinsics(value: Any) -> dict[int, np.ndarray]:
    if not isinstance(value, dict):
        raise JobError("intrinsics must map camera numbers to 3x3 matrices, e.g. {\"0\": [[f, 0, cx], [0, f, cy], [0, 0, 1]]}")
    out = {}
    for k, v in value.items():
        try:
            K = np.asarray(v, np.float64)
            camera = int(k)
        except (TypeError, ValueError):
            raise JobError(f"intrinsics for camera {k} must be a 3x3 matrix") from None
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise JobError(f"intrinsics for camera {k} must be a 3x3 matrix")
        out[camera] = K
    return out


# ---------------------------------------------------------------------- calibrate
@dataclass(frozen=True)
class CalibrateOptions:
    """Calibrate the rig's projectors with the camera(s) (see :mod:`coordinator.calibration.calibrate_job`)."""

    mode: str | None = option(None, choices=("multiplexed", "sequential"), group=WHAT,
                              help="'multiplexed': every projector at once, captures independent of their number "
                                   "(on a table or a mesh); 'sequential': Gray codes, one projector after another "
                                   "(default: multiplexed on a table, sequential on a mesh)")
    surface: str | None = option(None, choices=("table", "mesh"), group=WHAT,
                                 help="what the projectors light (default: mesh when a mesh is given, else table)")
    slots: list[str] | None = option(None, group=WHAT, help="only these projectors (default: every connected one)")
    table_mm: tuple[float, float] = option((1200.0, 600.0), lo=1, metavar="WxH", group=WHAT, label="Table size (mm)",
                                           help="table size in mm; the content spans it")
    table_points: str | dict | list | None = option(
        None, parse=_path_or_document("table_points", rows=True), metavar="FILE", group=WHAT,
        help="known table points: a points file (read by the command line and sent with the job), or in "
             "rig.toml [[x_mm, y_mm, u_px, v_px], ...] seen by camera 0")
    charuco: dict | None = option(None, parse=_board, metavar="FILE", group=WHAT, label="ChArUco board",
                                  help="a ChArUco board lying on the table: JSON or TOML with squares_x, squares_y, "
                                       "square_mm, marker_mm, dictionary, origin_mm (read by the command line); "
                                       "without it nor table points, the rig's board.json (`shadowless rig board`) "
                                       "or the default printed board is looked for on the table")
    mesh: str | None = option(None, parse=_file_path("mesh"), metavar="PATH", group=WHAT,
                              help="OBJ/PLY mesh of the object (a path on the coordinator's machine)")
    landmarks: str | dict | None = option(None, parse=_path_or_document("landmarks"), metavar="FILE", group=WHAT,
                                          help="mesh landmarks clicked in the camera (points file, read by the "
                                               "command line; frame 'world' or 'model')")
    intrinsics: dict | None = option(None, parse=_intrinsics, cli=False,
                                     help="known camera intrinsics for 3D: {camera index: 3x3 K}")
    use_table: bool = option(True, flag="--table", group=WHAT,
                             help="3D: also use the table plane around the object (--no-table: the object only)")
    table_only: bool = option(False, group=WHAT,
                              help="only map the table into the camera(s) (e.g. from a ChArUco board) and save it; "
                                   "remove the board, then calibrate without table points or board to reuse it")
    settle_s: float = option(0.1, lo=0, hi=30, flag="--settle", metavar="S", group=CAPTURES,
                             help="wait after every node swapped a pattern in, before capturing (seconds)")
    record: str | None = option(None, metavar="DIR", group=CAPTURES,
                                help="save every capture under DIR/camera<i>/ (on the coordinator's machine) for replay "
                                     "with --camera folder:DIR/camera0")
    min_pixels: int = option(2000, lo=12, group=CAPTURES,
                             help="sequential: fewest decoded camera pixels a projector needs")
    min_contrast: float = option(0.004, lo=0, hi=1, group=CAPTURES,
                                 help="white - black below this (fraction of full scale) is shadow")
    max_saturated: float = option(0.02, lo=0, hi=1, group=CAPTURES, label="Saturated pixels allowed (fraction)",
                                  help="over-exposure limit: fraction of the lit camera pixels that may saturate")
    rounds: int = option(4, lo=1, hi=16, group=CAPTURES,
                         help="multiplexed: lattice captures (more are added when a projector would get too few dots)")
    seed: int = option(0, group=CAPTURES, help="multiplexed: dot placement seed")
    force: bool = option(False, label="Start a new run", help="start a new run instead of resuming an interrupted one")
    keep_going: bool = option(True, help="go on with the other projectors when one fails (--stop-on-error: stop)")

    def validate(self) -> None:
        if not 0 < self.min_contrast < 1:
            raise JobError(f"min_contrast must be in (0, 1), got {self.min_contrast!r}")
        if not 0 < self.max_saturated <= 1:
            raise JobError(f"max_saturated must be in (0, 1], got {self.max_saturated!r}")
        # mode and surface default to what the mesh implies: decide() settles and checks them


def _rig_section(rig_dir: Path) -> tuple[Path, dict]:
    """rig.toml's ``[calibration]`` table ({} when there is none)."""
    toml = rig_dir / "rig.toml"
    if not toml.exists():
        return toml, {}
    try:
        section = tomllib.loads(toml.read_text()).get("calibration", {})
    except tomllib.TOMLDecodeError as exc:
        raise JobError(f"{toml}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise JobError(f"{toml}: cannot read it: {exc.strerror or exc}") from exc
    if not isinstance(section, dict):
        raise JobError(f"{toml}: [calibration] must be a table")
    known = {f.name for f in dataclasses.fields(CalibrateOptions)}
    bad = sorted(set(section) - known)
    if bad:
        raise JobError(f"{toml}: unknown [calibration] key(s) {', '.join(bad)}")
    return toml, section


def rig_defaults(rig_dir: str | Path) -> tuple[dict, str]:
    """rig.toml's ``[calibration]`` table, the defaults under a request's options, and its name."""
    toml, section = _rig_section(Path(rig_dir))
    return section, f"{toml} [calibration]"


def decide(opts: CalibrateOptions) -> CalibrateOptions:
    """``opts`` with ``surface`` and ``mode`` settled (see the fields' help) and checked together."""
    surface = opts.surface or ("mesh" if opts.mesh else "table")
    if surface == "mesh" and not opts.mesh:
        raise JobError("surface 'mesh' needs a mesh file (parameter or [calibration] mesh = \"object.obj\")")
    mode = opts.mode or ("multiplexed" if surface == "table" else "sequential")
    return dataclasses.replace(opts, surface=surface, mode=mode)


# ---------------------------------------------------------------------- resolution
@dataclass(frozen=True, eq=False)
class Inputs:
    """What the file and document options resolve to (:func:`resolve`)."""

    table_points: list[PointSet]
    charuco: CharucoSpec | None
    mesh_path: str | None
    landmarks: list[PointSet]
    intrinsics: dict[int, np.ndarray]
    #: without table points nor a board given: the board looked for on the table (the rig's
    #: board.json, else :data:`~imaging.calibration.board.DEFAULT_BOARD`), and where it came from
    auto_board: CharucoSpec | None = None
    auto_board_source: str = ""


def _path(value: str, rig_dir: Path) -> Path:
    """Absolute paths as given; relative ones against the rig directory (where rig.toml names them)."""
    p = Path(value)
    return p if p.is_absolute() else rig_dir / p


def _point_sets(value: str | dict, what: str, rig_dir: Path) -> list[PointSet]:
    if isinstance(value, dict):      # a points document sent inline (the command line reads local files)
        return parse_points(value, source=what)
    return read_points(_path(value, rig_dir))


def resolve(opts: CalibrateOptions, rig_dir: str | Path) -> Inputs:
    """Read the points files, check the board description and make paths absolute; a
    :class:`JobError` names the file or the entry at fault."""
    rig_dir = Path(rig_dir)
    try:
        tp = opts.table_points
        if tp is None:
            table_points = []
        elif isinstance(tp, list):
            table_points = inline_table_points(tp, source="table_points")
        else:
            table_points = _point_sets(tp, "table_points", rig_dir)
            if any(s.frame != "world" for s in table_points):
                raise JobError("table_points must be in the world frame (points on the table)")
        charuco = CharucoSpec.from_dict(opts.charuco) if opts.charuco is not None else None
        auto, source = (None, "") if table_points or charuco is not None else _auto_board(rig_dir)
        landmarks = _point_sets(opts.landmarks, "landmarks", rig_dir) if opts.landmarks is not None else []
    except CalibrationError as exc:
        raise JobError(str(exc)) from exc
    except (TypeError, ValueError) as exc:
        raise JobError(f"bad calibration parameter: {exc or 'a value has the wrong type'}") from exc
    mesh_path = str(_path(opts.mesh, rig_dir)) if opts.mesh else None
    return Inputs(table_points, charuco, mesh_path, landmarks, dict(opts.intrinsics or {}), auto, source)


def _auto_board(rig_dir: Path) -> tuple[CharucoSpec, str]:
    """The board calibrate looks for on the table when it is given neither points nor a board."""
    f = rig_dir / BOARD_FILE
    if not f.exists():
        return DEFAULT_BOARD, "the default board of `shadowless rig board`"
    try:
        doc = json.loads(f.read_text())
    except (OSError, ValueError) as exc:
        raise JobError(f"{f}: not a board description ({exc})") from None
    if not isinstance(doc, dict):
        raise JobError(f"{f}: not a board description (a JSON object with squares_x, squares_y, square_mm, ...)")
    return CharucoSpec.from_dict(doc), f"the board of {f}"


# ---------------------------------------------------------------------- alignment
@dataclass(frozen=True)
class AlignmentOptions:
    """Measure each projector's residual misalignment (see :mod:`coordinator.calibration.alignment_job`)."""

    slots: list[str] | None = option(None, help="only these projectors (default: every connected one)")
    rounds: int = option(2, lo=1, hi=16, help="lattice captures")
    settle_s: float = option(0.1, lo=0, hi=30, flag="--settle", metavar="S",
                             help="wait after every node swapped a pattern in, before capturing (seconds)")
    camera: int = option(0, lo=0, flag="--camera-index", metavar="I", help="which calibrated camera to use")
    record: str | None = option(None, metavar="DIR",
                                help="save every capture under DIR/camera<i>/ (on the coordinator's machine)")
    heatmap_width: int = option(600, lo=16, hi=8192, metavar="PX", help="width of the heat map image")
