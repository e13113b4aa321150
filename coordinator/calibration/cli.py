"""`shadowless calibrate` and `shadowless alignment`: run the calibration jobs on the coordinator.

Files named on the command line (known table points, landmarks, a ChArUco board
description) are read here and sent with the job, so the coordinator may run
on another machine; the mesh and ``--record`` are paths on the coordinator's
machine.
"""
from __future__ import annotations

import argparse
import json
import math
import tomllib
from pathlib import Path

from coordinator.jobclient import run_job_command
from coordinator.operator import add_connection_args

EXAMPLES = """\
examples:
  shadowless calibrate --rig-dir rigs/table --table-points marks.json
  shadowless calibrate --rig-dir rigs/table --charuco board.json --table-only   # then remove the board:
  shadowless calibrate --rig-dir rigs/table                                      # reuses the saved table mapping
  shadowless calibrate --rig-dir rigs/table --mode sequential --slots r0c0,r0c1
  shadowless calibrate --rig-dir rigs/table --table-points marks.json --record /tmp/cal-run1
  shadowless calibrate --rig-dir rigs/table --camera folder:/tmp/cal-run1/camera0 --force   # replay offline
  shadowless calibrate --rig-dir rigs/bust --mesh bust.obj --landmarks clicks.json --table-points marks.json
  shadowless alignment --rig-dir rigs/table

A points file (JSON) lists known points and where the camera sees them:
  {"frame": "world", "points": [{"name": "corner", "xy": [-560, 260], "pixel": [41.3, 37.9]}, ...]}
("xy" on the table, or "xyz"; "frame": "model" for landmarks in a mesh's own coordinates).
Known table points may also live in rig.toml:  [calibration]  table_points = [[x_mm, y_mm, u_px, v_px], ...]
An interrupted run resumes where it stopped; --force starts afresh.
"""


def _size(text: str) -> list[float]:
    try:
        w, h = (float(v) for v in text.lower().replace("x", " ").split())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH in mm, e.g. 1200x600, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError("sizes must be positive")
    return [w, h]


def _slots(text: str) -> list[str]:
    out = [s.strip() for s in text.split(",") if s.strip()]
    if not out:
        raise argparse.ArgumentTypeError("expected slot names, e.g. r0c0,r0c1")
    return out


def configure_calibrate(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Calibrate the rig's projectors with the camera(s): each projector's pose (content -> projector\n"
        "homography on a table, or a 3x4 projection onto a mesh) is computed, stored in the rig directory\n"
        "and pushed to its node as soon as it is done. Modes: 'multiplexed' (default on a table) shows every\n"
        "projector's patterns at once, so the captures do not grow with the number of projectors;\n"
        "'sequential' is the reference Gray-code method, one projector after another."
    )
    p.epilog = EXAMPLES
    add_connection_args(p)
    g = p.add_argument_group("what to calibrate")
    g.add_argument("--mode", choices=["multiplexed", "sequential"], help="default: multiplexed on a table, sequential on a mesh")
    g.add_argument("--surface", choices=["table", "mesh"], help="default: mesh when --mesh is given, else table")
    g.add_argument("--slots", type=_slots, metavar="A,B,...", help="only these projectors (default: every connected one)")
    g.add_argument("--table-mm", type=_size, metavar="WxH", help="table size in mm (default 1200x600); the content spans it")
    g.add_argument("--table-points", metavar="FILE", help="known table points (points file, read here)")
    g.add_argument("--charuco", metavar="FILE", help="ChArUco board lying on the table: JSON or TOML with squares_x, "
                   "squares_y, square_mm, marker_mm, dictionary, origin_mm")
    g.add_argument("--mesh", metavar="PATH", help="OBJ/PLY mesh of the object (path on the coordinator's machine)")
    g.add_argument("--landmarks", metavar="FILE", help="mesh landmarks clicked in the camera (points file, read here)")
    g.add_argument("--no-table", action="store_true", help="3D: do not use the table around the object")
    g.add_argument("--table-only", action="store_true", help="only map the table into the camera(s) (e.g. from a ChArUco "
                   "board) and save it; remove the board, then calibrate without --charuco/--table-points to reuse it")
    c = p.add_argument_group("cameras and captures")
    c.add_argument("--camera", action="append", metavar="SPEC",
                   help="camera(s) for this run: room://HOST:PORT, opencv:INDEX, /dev/videoN, folder:DIR (default: the coordinator's)")
    c.add_argument("--settle", type=float, metavar="S", help="wait after every swap before capturing (default 0.1 s)")
    c.add_argument("--record", metavar="DIR", help="save every capture under DIR/camera<i>/ (on the coordinator's machine) for replay")
    c.add_argument("--min-pixels", type=int, metavar="N", help="fewest decoded camera pixels per projector (default 2000)")
    c.add_argument("--rounds", type=int, metavar="N", help="multiplexed: lattice captures (default 4)")
    c.add_argument("--seed", type=int, help="multiplexed: dot placement seed (default 0)")
    r = p.add_argument_group("run")
    r.add_argument("--force", action="store_true", help="start a new run instead of resuming an interrupted one")
    r.add_argument("--stop-on-error", action="store_true", help="stop at the first projector that fails (default: go on)")
    r.add_argument("--json", action="store_true", help="print the result as JSON")


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


def calibrate_params(args: argparse.Namespace) -> dict:
    """The job parameters the command line describes."""
    params: dict = {}
    for key, attr in (("mode", "mode"), ("surface", "surface"), ("slots", "slots"), ("table_mm", "table_mm"),
                      ("settle_s", "settle"), ("record", "record"), ("min_pixels", "min_pixels"), ("rounds", "rounds"),
                      ("seed", "seed")):
        value = getattr(args, attr, None)
        if value is not None:
            params[key] = value
    if args.record:
        params["record"] = str(Path(args.record).absolute())
    if args.table_points:
        params["table_points"] = _read_doc(args.table_points, "table points")
    if args.landmarks:
        params["landmarks"] = _read_doc(args.landmarks, "landmarks")
    if args.charuco:
        params["charuco"] = _read_doc(args.charuco, "ChArUco board")
    if args.mesh:
        m = Path(args.mesh)
        params["mesh"] = str(m.absolute()) if m.exists() else args.mesh
    if args.no_table:
        params["use_table"] = False
    if args.table_only:
        params["table_only"] = True
    if args.force:
        params["force"] = True
    if args.stop_on_error:
        params["keep_going"] = False
    if args.camera:
        params["cameras"] = list(args.camera)
    return params


def _fmt(v, nd: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"


def calibrate_report(result: dict) -> str:
    if not result.get("slots") and not result.get("failed"):
        cams = ", ".join(f"camera {c['camera']} ({_fmt(c.get('table_rms_px'))} px)" for c in result.get("camera_setup", []))
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
    p.epilog = "examples:\n  shadowless alignment --rig-dir rigs/table\n  shadowless alignment --rig-dir rigs/table --slots r0c0,r2c2 --json"
    add_connection_args(p)
    p.add_argument("--slots", type=_slots, metavar="A,B,...", help="only these projectors (default: every connected one)")
    p.add_argument("--rounds", type=int, metavar="N", help="lattice captures (default 2)")
    p.add_argument("--settle", type=float, metavar="S", help="wait after every swap before capturing (default 0.1 s)")
    p.add_argument("--camera-index", type=int, metavar="I", help="which calibrated camera to use (default 0)")
    p.add_argument("--camera", action="append", metavar="SPEC", help="camera spec(s) for this run (default: the coordinator's)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def alignment_params(args: argparse.Namespace) -> dict:
    params: dict = {}
    if args.slots:
        params["slots"] = args.slots
    if args.rounds is not None:
        params["rounds"] = args.rounds
    if args.settle is not None:
        params["settle_s"] = args.settle
    if args.camera_index is not None:
        params["camera"] = args.camera_index
    if args.camera:
        params["cameras"] = list(args.camera)
    return params


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
    return "\n".join(lines)


def run_alignment(args: argparse.Namespace) -> int:
    return run_job_command(args, "alignment", alignment_params(args), report=alignment_report)


configure = configure_calibrate
run = run_calibrate
