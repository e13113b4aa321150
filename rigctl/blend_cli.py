"""`shadowless blend`: measure each projector's light through the camera and blend the rig.

Runs the coordinator's ``blend`` job (:mod:`coordinator.blending.blend_job`) and prints its figures;
the flags come from the job's options (:class:`coordinator.blending.blend_options.BlendOptions`).
"""
from __future__ import annotations

import argparse
import math

from coordinator.blending.blend_options import BlendOptions
from coordinator.jobs.options import add_arguments, params_from_args
from rigctl.client import add_connection_args
from rigctl.job_command import run_job_command

DESCRIPTION = """\
Blend the rig: make the light of every projector that reaches a point add up to one even light.

What it measures: each projector's light at full white over the surface, through the camera, and the
rig's black. Every projector shows small white blobs at once, each on camera sites of its own, so 25
projectors take about twice the captures of one. From a smooth model of each projector's light (its
fall-off, hot spot, brightness and white point) it computes a target every covered point can reach
(smooth, so that the eye sees no gradient; not the darkest point everywhere, which would throw most of
the light away) and, per projector, an alpha map (a gain per channel) and a beta map (a black offset
that evens the black floor where fewer projectors overlap). Each node applies its maps in its shader
before its LUT; footprint edges fade in and out, so no seam shows.

When to run it: after `shadowless calibrate` (where each projector's pixels land) and `shadowless
response` (the LUTs: the blend works in linear light), in that order; again whenever a projector is
moved, replaced or refocused, a lamp is changed or has aged (the watchdog's lamp gains say so), or the
surface changes. Run `shadowless transport` and `compensate` after it: they then measure the blended rig.

Headroom: a blend keeps some light in reserve so that losing a projector (a node that drops, a lamp
that dies) can be covered by the others without a visible change: the coordinator re-blends from the
stored measurement with no new capture. 'auto' (the default) keeps exactly enough to lose any one
projector wherever others reach: on an N-fold overlap about 1/N of the brightness (4 % on 25, 11 % on
9, half of a two-projector overlap). A fraction H keeps H of every point's light. The result prints
what the headroom costs in brightness; --headroom 0 spends it all on brightness, with no failover margin.

The result: non-uniformity of a flat white before and after (p99 of |I / target - 1| over the covered
area), per channel after, the largest step across a footprint edge, the captures, and the cost of the
headroom. The maps, the figures, the before/after pictures and the measured light are stored in the rig
directory (blend/); the console shows them.
"""

EXAMPLES = """\
examples:
  shadowless calibrate --rig-dir rigs/table && shadowless response --rig-dir rigs/table
  shadowless blend --rig-dir rigs/table                      # headroom auto: any one projector may fail
  shadowless blend rigs/table --headroom 0                   # brightest blend, no reserve for a failure
  shadowless blend rigs/wall --headroom 0.2 --map-scale 2    # 20 % reserve, finer maps
  shadowless blend rigs/table --frames 4 --json              # average 4 captures per pattern; JSON result
"""


def configure(p: argparse.ArgumentParser) -> None:
    p.description = DESCRIPTION
    p.epilog = EXAMPLES
    p.add_argument("rig", nargs="?", metavar="RIG", help="the rig directory (same as --rig-dir)")
    add_connection_args(p)
    add_arguments(p, BlendOptions)
    p.add_argument("--camera", dest="cameras", action="append", metavar="SPEC",
                   help="camera(s) for this run: room://HOST:PORT, opencv:INDEX, ... (default: the coordinator's)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _pct(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{100 * v:.2f} %"


def report(result: dict) -> str:
    colour = result.get("colour_after") or []
    lines = [
        f"blend {result.get('blend_id', '')[:8]} of {len(result.get('slots', []))} projector(s): "
        f"{result.get('captures')} captures ({result.get('blob_captures')} black and blob captures), "
        f"{result.get('wall_s', 0):.1f} s",
        f"non-uniformity of a flat white: {_pct(result.get('uniformity_before'))} before, "
        f"{_pct(result.get('uniformity_after'))} after (the measured light predicts {_pct(result.get('uniformity_predicted'))})",
        "per channel after: " + " / ".join(_pct(v) for v in colour),
        f"largest step across a footprint edge: {_pct(result.get('seam_before'))} before, {_pct(result.get('seam_after'))} after",
        f"headroom {result.get('headroom_mode')}: {_pct(result.get('headroom'))} of the light held back (median), "
        f"costing {_pct(result.get('brightness_cost'))} of the brightness",
    ]
    alone = {s: v for s, v in (result.get("uncovered") or {}).items() if v and v > 0.05}
    if alone:
        lines.append("no other projector reaches: " + ", ".join(f"{s} {_pct(v)} of its footprint" for s, v in alone.items())
                     + " (a failure there goes dark)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.rig and not args.rig_dir:
        args.rig_dir = args.rig
    params = params_from_args(BlendOptions, args)
    if args.cameras:
        params["cameras"] = list(args.cameras)
    return run_job_command(args, "blend", params, report=report)
