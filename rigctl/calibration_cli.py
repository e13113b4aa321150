"""`shadowless calibrate` and `shadowless alignment`: run the calibration jobs on the coordinator.

The job options' flags come from their definitions (:mod:`coordinator.calibration.options`);
only what the operator gives is sent, the defaults are the job's. Files named on the command
line (known table points, landmarks, a ChArUco board description) are read here and sent
with the job, so the coordinator may run on another machine; the mesh and ``--record`` are
paths on the coordinator's machine.
"""
from __future__ import annotations

import argparse
import json
import math
import tomllib
from pathlib import Path

from coordinator.calibration.options import AlignmentOptions, CalibrateOptions
from rigctl.client import add_connection_args
from rigctl.job_command import run_job_command
from coordinator.jobs import add_arguments, params_from_args

EXAMPLES = """\
examples:
  shadowless rig board rigs/table                                # print its board.pdf, lay it on the table:
  shadowless calibrate --rig-dir rigs/table --table-only          # finds the board; then remove the board:
  shadowless calibrate --rig-dir rigs/table                       # reuses the saved table mapping
  shadowless calibrate --rig-dir rigs/table --table-points marks.json
  shadowless calibrate --rig-dir rigs/table --charuco my-board.json --table-only   # a board of your own
  shadowless calibrate --rig-dir rigs/table --mode sequential --slots r0c0,r0c1
  shadowless calibrate --rig-dir rigs/table --table-points marks.json --record /var/lib/shadowless/records/cal-run1
  shadowless calibrate --rig-dir rigs/table --camera folder:/var/lib/shadowless/records/cal-run1/camera0 --force   # replay offline
  shadowless calibrate --rig-dir rigs/bust --mesh bust.obj --landmarks clicks.json --table-points marks.json
  shadowless calibrate --rig-dir rigs/bust --mesh bust.obj --landmarks clicks.json --table-points marks.json --mode multiplexed
  shadowless alignment --rig-dir rigs/table

A points file (JSON) lists known points and where the camera sees them:
  {"frame": "world", "points": [{"name": "corner", "xy": [-560, 260], "pixel": [41.3, 37.9]}, ...]}
("xy" on the table, or "xyz"; "frame": "model" for landmarks in a mesh's own coordinates).
Any option may also be set for the rig in rig.toml, e.g.
  [calibration]
  mode = "sequential"
  table_points = [[x_mm, y_mm, u_px, v_px], ...]
(the command line wins). An interrupted run resumes where it stopped; --force starts afresh.
Without table points or --charuco, calibrate looks for the rig's board (RIG/board.json, what
`shadowless rig board RIG` writes; else the default printed board) in the camera image; when it
is not on the table, the table mapping an earlier run saved serves.
"""

ALIGNMENT_EXAMPLES = """\
examples:
  shadowless alignment --rig-dir rigs/table
  shadowless alignment --rig-dir rigs/table --slots r0c0,r2c2 --json
"""

#: Options naming local files the command line reads and sends with the job (option -> what it is).
_LOCAL_DOCUMENTS = {"table_points": "table points", "landmarks": "landmarks", "charuco": "ChArUco board"}


def _camera_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", dest="cameras", action="append", metavar="SPEC",
                   help="camera(s) for this run: room://HOST:PORT, opencv:INDEX, /dev/videoN, folder:DIR "
                        "(default: the coordinator's)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def configure_calibrate(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Calibrate the rig's projectors with the camera(s): each projector's pose (content -> projector\n"
        "homography on a table, or a 3x4 projection onto a mesh) is computed, stored in the rig directory\n"
        "and pushed to its node as soon as it is done. Modes: 'multiplexed' (default on a table) shows every\n"
        "projector's patterns at once, so the captures do not grow with the number of projectors (on a\n"
        "mesh too, with --mode multiplexed); 'sequential' (default on a mesh) is the reference Gray-code\n"
        "method, one projector after another.\n"
        "Files named here (points, landmarks, a board) are read here and sent with the job; the mesh\n"
        "and --record are paths on the coordinator's machine."
    )
    p.epilog = EXAMPLES
    add_connection_args(p)
    _camera_args(p)
    p.add_argument("--stop-on-error", dest="keep_going", action="store_false", default=argparse.SUPPRESS,
                   help="stop at the first projector that fails (default: calibrate the others)")
    add_arguments(p, CalibrateOptions, exclude=("keep_going",))


def _read_doc(path: str, what: str) -> dict:
    f = Path(path)
    try:
        text = f.read_text()
    except OSError as exc:
        raise SystemExit(f"shadowless calibrate: cannot read {what} {f}: {exc.strerror or exc}") from None
    try:
        return tomllib.loads(text) if f.suffix.lower() == ".toml" else json.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SystemExit(f"shadowless calibrate: {what} {f} is not valid {'TOML' if f.suffix == '.toml' else 'JSON'}: {exc}") from None


def _with_cameras(params: dict, args: argparse.Namespace) -> dict:
    if params.get("record"):
        params["record"] = str(Path(params["record"]).absolute())
    if args.cameras:
        params["cameras"] = list(args.cameras)
    return params


def calibrate_params(args: argparse.Namespace) -> dict:
    """The job parameters the command line describes (only what the operator gave: the
    defaults are the job's, applied on the coordinator after rig.toml's)."""
    params = params_from_args(CalibrateOptions, args)
    for key, what in _LOCAL_DOCUMENTS.items():
        if key in params:
            params[key] = _read_doc(params[key], what)
    if "mesh" in params:
        m = Path(params["mesh"])
        params["mesh"] = str(m.absolute()) if m.exists() else params["mesh"]
    return _with_cameras(params, args)


def _fmt(v, nd: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"


def calibrate_report(result: dict) -> str:
    if not result.get("slots") and not result.get("failed"):
        cams = ", ".join(f"camera {c['camera']} (fit residual {_fmt(c.get('table_rms_px'))} px rms)"
                         for c in result.get("camera_setup", []))
        return f"table mapped and saved: {cams}; remove any board from the table, then run `shadowless calibrate` again"
    lines = [f"calibration run {result.get('run')}: {result.get('mode')} mode on the {result.get('surface')}, "
             f"{result.get('captures')} captures in {_fmt(result.get('wall_s'), 1)} s"
             + (" (resumed)" if result.get("resumed") else "")]
    lines.append(f"{'slot':<10} {'rms px':>8} {'max px':>8} {'points':>8}  note")
    for slot, d in result.get("slots", {}).items():
        note = "from an earlier part of this run" if d.get("resumed") else ""
        lines.append(f"{slot:<10} {_fmt(d.get('rms_px')):>8} {_fmt(d.get('max_px')):>8} {d.get('points', 0):>8}  {note}".rstrip())
    for slot, msg in result.get("failed", {}).items():
        lines.append(f"{slot:<10} {'failed':>8}  {msg}")
    lines.append("rms/max: residuals of the fitted pose at the measured points (projector pixels); "
                 "`shadowless alignment` measures the rig as it now projects")
    return "\n".join(lines)


def run_calibrate(args: argparse.Namespace) -> int:
    return run_job_command(args, "calibrate", calibrate_params(args), report=calibrate_report)


def configure_alignment(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Check the rig's alignment: every projector shows a fine dot lattice through its current pose, all at\n"
        "once; the camera measures where each dot lands. Prints each projector's residual misalignment\n"
        "(projector pixels) and writes a heat map over the table (calibration/alignment.png in the rig directory)."
    )
    p.epilog = ALIGNMENT_EXAMPLES
    add_connection_args(p)
    _camera_args(p)
    add_arguments(p, AlignmentOptions)


def alignment_params(args: argparse.Namespace) -> dict:
    return _with_cameras(params_from_args(AlignmentOptions, args), args)


def alignment_report(result: dict) -> str:
    lines = [f"{'slot':<10} {'rms px':>8} {'p95 px':>8} {'max px':>8} {'dots':>6}  worst at (mm)"]
    lines[0] += " (mm on the table, or camera px on a mesh)"
    for slot, d in result.get("slots", {}).items():
        at = d.get("worst_at_mm", d.get("worst_at_camera_px"))
        lines.append(f"{slot:<10} {_fmt(d.get('rms_px')):>8} {_fmt(d.get('p95_px')):>8} {_fmt(d.get('max_px')):>8} "
                     f"{d.get('dots', 0):>6}  {'' if at is None else f'({at[0]:.0f}, {at[1]:.0f})'}{d.get('note', '')}")
    if result.get("worst_slot"):
        lines.append(f"worst: {result['worst_slot']} ({_fmt(result.get('worst_rms_px'))} px rms)")
    for m in result.get("heatmaps", [{"file": result.get("heatmap"), "frame": "table mm"}]):
        lines.append(f"heat map: {m['file']} over the {'table' if m['frame'] == 'table mm' else 'camera image'} "
                     f"(red = {result.get('heatmap_full_scale_px', 1)} px or more)")
        if m.get("figure"):
            lines.append(f"figure with colour bar, axes and outlines: {m['figure']}")
    return "\n".join(lines)


def run_alignment(args: argparse.Namespace) -> int:
    return run_job_command(args, "alignment", alignment_params(args), report=alignment_report)


configure = configure_calibrate
run = run_calibrate
