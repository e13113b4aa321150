"""`shadowless coverage`: how many projectors reach each point of the object, from the rig's poses and mesh
(the calibrated poses, or with ``--planned`` those a layout planned: :mod:`coordinator.rig_layout`).

Offline: reads the rig directory (works while a coordinator serves it; writes only under
``coverage/``), computes, stores and draws the coverage (:func:`coordinator.coverage_run.compute_coverage`,
which the coordinator's ``coverage`` job runs too) and prints the per-slot summary.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from imaging.calibration.errors import CalibrationError
from rigctl.content_format import operator_table, rendered
from coordinator.coverage import DEFAULT_SHADOW_SCALE, DEFAULT_TEXTURE
from coordinator.coverage_run import compute_coverage, view
from coordinator.errors import RigError
from coordinator.rig import Rig
from protos import cli_types
from protos.wording import count

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
A running coordinator computes the same as its `coverage` job (the console's Jobs form), and the
console's Pictures panel shows the heat map and the per-slot table of the last run either way.
"""

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
    doc = compute_coverage(Rig(args.rig_dir), slots=args.slots, planned=args.planned, views=args.views,
                           texture=args.texture, shadow_scale=args.shadow_scale, falloff=args.falloff,
                           panel=args.panel, out=args.out, progress=_progress)
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
    lines = [f"rig {doc['rig']}  mesh {doc['mesh']}  {count(doc['slots'], 'projector')}{planned}  texture "
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
