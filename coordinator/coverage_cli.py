"""`shadowless coverage`: how many projectors reach each point of the object, from the rig's poses and mesh
(the calibrated poses, or with ``--planned`` those a layout planned: :mod:`coordinator.rig_layout`).

Offline: reads the rig directory (works while a coordinator serves it; writes only under
``coverage/``), computes the coverage per texel (:mod:`coordinator.coverage`), stores it
(:mod:`coordinator.coverage_store`), draws the heat map (:mod:`coordinator.coverage_figure`) and
prints the per-slot summary.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path

import numpy as np

from coordinator.calibration.errors import CalibrationError
from coordinator.content_format import operator_table, rendered
from coordinator.coverage import DEFAULT_SHADOW_SCALE, DEFAULT_TEXTURE, CoverageModel
from coordinator.coverage_figure import coverage_picture, orbit_camera
from coordinator.coverage_store import (
    coverage_dir,
    rig_camera,
    rig_projectors,
    save_coverage,
)
from coordinator.errors import RigError
from coordinator.rig import Rig
from coordinator.store import atomic_write_bytes
from protos import cli_types

EXAMPLES = """\
examples:
  shadowless coverage --rig-dir rigs/bust                        # front and back views
  shadowless coverage --rig-dir rigs/bust --view 30,20 --view 210,20 --out bust-coverage.png
  shadowless coverage --rig-dir rigs/bust --view camera          # as the rig's calibrated camera 0 sees it
  shadowless coverage --rig-dir rigs/bust --slots r0c0,r0c2,r2c2 --json   # what a subset would reach
  shadowless rig init rigs/plan --layout plan.toml && shadowless coverage --rig-dir rigs/plan --planned
                                                                 # a plan's coverage before any hardware

--planned reads the poses a layout planned (`shadowless rig init DIR --layout FILE`: each projector's
position, aim and focal length onto the layout's object, or onto its table when it has none), so its
figures are for the projectors as planned, not as hung; a slot's calibration replaces its planned pose.

A view is AZ,EL in degrees around the object's centre: azimuth about the vertical, 0 on the +y
side (the front of an object facing +y), 90 on +x, 180 behind; elevation above the horizontal.
Written under DIR/coverage/: coverage.npz (per texel: count, reach, irradiance, area),
coverage.json (the summary) and coverage.png (unless --out names another file).
"""

_VIEW = re.compile(r"^camera(?::(\d+))?$")


def view(text: str) -> tuple[str, object]:
    """``"30,20"`` -> ("orbit", (30.0, 20.0)); ``"camera"`` / ``"camera:1"`` -> ("camera", index)."""
    m = _VIEW.match(text.strip())
    if m:
        return "camera", int(m.group(1) or 0)
    try:
        az, el = cli_types.pair(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a view: AZ,EL in degrees (e.g. 30,20) or camera[:N]") from None
    if not -90.0 <= el <= 90.0:
        raise argparse.ArgumentTypeError(f"{text!r}: the elevation must be -90..90 degrees")
    return "orbit", (az, el)


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "How many projectors reach each point of the object the rig projects onto, and each one's share of\n"
        "the light there, from the calibrated 3D poses and the mesh alone (nothing is shown or captured).\n"
        "Where few projectors reach, a hand casts a deeper, larger shadow. Per texel of the mesh's texture:\n"
        "inside the projector's image, facing it, not hidden by the object (a shadow map per projector);\n"
        "irradiance = gain x cos(incidence) x (1 m / distance)^2 x cos(off-axis)^(falloff - 3).\n"
        "With --planned, from the poses a layout planned (`rig init --layout`), before any projector hangs:\n"
        "the figures are then for the plan, onto its object or its table.")
    p.epilog = EXAMPLES
    p.add_argument("--rig-dir", required=True, metavar="DIR", help="the rig directory (read; results go to DIR/coverage/)")
    p.add_argument("--view", dest="views", action="append", type=view, metavar="AZ,EL|camera[:N]",
                   help="a viewpoint of the picture (repeat for several panels; default 0,20 and 180,20)")
    p.add_argument("--out", metavar="PNG", help="the picture (default DIR/coverage/coverage.png)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON instead of a table")
    p.add_argument("--slots", type=cli_types.names, metavar="A,B,...", help="only these slots (default: every slot with a 3D pose)")
    p.add_argument("--planned", action="store_true",
                   help="the planned poses of a rig made by `rig init --layout` (before any hardware) instead of the "
                        "calibrated ones: the figures are for the plan")
    p.add_argument("--texture", type=cli_types.size, default=DEFAULT_TEXTURE, metavar="WxH",
                   help=f"texels sampled over the mesh's UV texture (default {DEFAULT_TEXTURE[0]}x{DEFAULT_TEXTURE[1]})")
    p.add_argument("--shadow-scale", type=cli_types.int_range(1, 8), default=DEFAULT_SHADOW_SCALE, metavar="N",
                   help=f"shadow-map pixels per projector pixel and axis (default {DEFAULT_SHADOW_SCALE})")
    p.add_argument("--falloff", type=cli_types.number(0, 10), default=1.0,
                   help="the lenses' fall-off exponent f: light towards the image edge x cos^f (default 1)")
    p.add_argument("--panel", type=cli_types.size, default=(480, 480), metavar="WxH", help="size of each view (default 480x480)")


def _progress(text: str) -> None:
    print(f"coverage: {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except (RigError, CalibrationError, ValueError, OSError) as exc:
        raise SystemExit(" ".join(str(exc).split())) from None


def _run(args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    rig = Rig(args.rig_dir)
    mesh, projectors = rig_projectors(rig, args.slots, planned=args.planned)
    flat = float(np.ptp(mesh.vertices[:, 2])) < 1e-6          # a table: seen from above
    views = []
    for kind, value in args.views or ([("orbit", (0.0, 90.0))] if flat else [("orbit", (0.0, 20.0)), ("orbit", (180.0, 20.0))]):
        if kind == "camera":
            views.append((f"camera {value}", rig_camera(rig.path, value)))
        else:
            az, el = value
            views.append((f"az {az:g} el {el:g}", orbit_camera(mesh.vertices, az, el, size=args.panel)))
    _progress(f"{len(projectors)} projectors{' as planned' if args.planned else ''} onto mesh {mesh.mesh_id} "
              f"({len(mesh.vertices)} vertices, {len(mesh.faces)} triangles): shadow maps")
    with CoverageModel(mesh.vertices, mesh.faces, mesh.uvs, projectors, shadow_scale=args.shadow_scale,
                       falloff=args.falloff) as model:
        _progress(f"sampling {args.texture[0]}x{args.texture[1]} texels")
        cov = model.texture(args.texture)
        _progress("drawing the picture")
        png, layout = coverage_picture(cov, model.raster, views)
    out = Path(args.out) if args.out else coverage_dir(rig.path) / "coverage.png"
    atomic_write_bytes(out, png)
    summary = cov.summary()
    doc = {**summary, "rig": rig.config.name, "mesh": mesh.mesh_id, "poses": "planned" if args.planned else "calibrated",
           "computed_at": time.time(),
           "seconds": round(time.monotonic() - t0, 2), "picture": str(out),
           "views": [label for label, _ in views], "layout": layout}
    npz, js = save_coverage(rig.path, cov, doc)
    doc["files"] = [str(npz), str(js), str(out)]
    if args.json:
        json.dump(doc, sys.stdout, indent=2)
        print()
    else:
        print(summary_text(doc, tty=sys.stdout.isatty()))
    return 0


def _fmt(v: float | None, nd: int = 1) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"


def summary_text(doc: dict, *, tty: bool = False) -> str:
    """The summary for an operator: the surface, the count over it, then one row per slot."""
    planned = " (as planned)" if doc.get("poses") == "planned" else ""
    lines = [f"rig {doc['rig']}  mesh {doc['mesh']}  {doc['slots']} projectors{planned}  texture "
             f"{doc['texture'][0]}x{doc['texture'][1]}  surface {doc['surface_mm2'] / 100:.0f} cm^2, "
             f"{_fmt(doc['lit_pct'])}% reached by at least one projector"]
    lines.append(f"projectors per point (by area): mean {_fmt(doc['count_mean'], 2)}, min {doc['count_min']}, "
                 f"5th percentile {doc['count_p5']}, median {doc['count_median']}; effective number "
                 f"{_fmt(doc['effective_mean'], 2)}; one blocked projector takes {_fmt(doc['max_share_mean_pct'])}% "
                 "of the light at most (mean over the surface)")
    t = operator_table("slot", ">reach cm^2", ">of surface %", ">of lit %", ">mean share %", ">sole cm^2")
    for slot, s in doc["per_slot"].items():
        t.add_row(slot, f"{s['reach_mm2'] / 100:.1f}", _fmt(s["reach_pct"]), _fmt(s["reach_pct_of_lit"]),
                  _fmt(s["mean_share_pct"], 2), f"{s['sole_mm2'] / 100:.1f}")
    lines.append(rendered(t, tty=tty))
    lines.append(f"wrote {', '.join(doc['files'])} ({doc['seconds']:.1f} s)")
    return "\n".join(lines)
