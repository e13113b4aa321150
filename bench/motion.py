"""`shadowless bench motion`: a hand waving over the table, the synthetic aperture against reactive compensation.

Runs the motion study (:mod:`sim.motion_cli`, ``shadowless study motion``) with
its defaults (5 s of a flat hand waving +-250 mm once a second 0.2 m above the
table, sampled at 60 fps, the room's ground truth at the 648 x 486 camera) and
reactive systems at 0, 50 and 100 ms, and prints one JSON document:

* ``systems``: per passive rig (P1 ... P25, P2) and reactive system
  (``reactive_100ms``: the 25 projectors re-solved 100 ms late, boosting;
  ``_suppress``: also switching off the blocked projectors on the hand; ``_P2``:
  the two-projector rig of prior systems) the time integrals over the run
  (``integrated_area_above_{10,50,90}_mm2_s``: area with at least that much
  drop x time; ``integrated_deficit_mm2_s``: light lost x time), ``max_drop``,
  ``umbra_visible_s`` and, for reactive systems, the over-bright ghosts
  (``integrated_area_overbright_above_10_mm2_s``, ``max_overbright``);
* ``comparison``: the reactive systems' integrals relative to passive P25's;
* ``targets``: P25's integrated umbra is 0; whether ``reactive_100ms`` shows an umbra;
* ``seconds``: the room's preparation and the per-frame cost of the ground truth.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from bench.machine import machine
from sim.motion_cli import add_motion_arguments, run_study


def configure(parser: argparse.ArgumentParser) -> None:
    add_motion_arguments(parser, latency="0,50,100")
    parser.add_argument("--out", type=Path, metavar="DIR", help="also write motion.json, motion.png and motion.mp4 here (as `shadowless study motion`)")
    parser.add_argument("--quick", action="store_true", help="0.3 s at 20 fps with a 259 x 194 camera (a smoke run)")


def _ratio(a: float, b: float) -> float | None:
    return round(a / b, 3) if b > 0 else None


def run(args: argparse.Namespace) -> int:
    if args.quick:
        args.duration, args.fps, args.camera_scale = 0.3, 20.0, 0.1
    doc, _ = run_study(args, out=args.out, show=["default"], progress=True)
    systems = doc["systems"]
    base = systems.get("P25")
    comparison = {}
    if base is not None:
        for name, s in systems.items():
            if s.get("reactive"):
                comparison[f"{name}_vs_P25"] = {
                    key: _ratio(s[key], base[key])
                    for key in ("integrated_area_above_10_mm2_s", "integrated_area_above_50_mm2_s", "integrated_deficit_mm2_s")
                }
    targets = {}
    if base is not None:
        targets["p25_integrated_umbra_is_0"] = base["integrated_area_above_90_mm2_s"] == 0
    if "reactive_100ms" in systems:
        r = systems["reactive_100ms"]
        targets["reactive_100ms_shows_an_umbra"] = r["integrated_area_above_90_mm2_s"] > 0
        targets["reactive_100ms_shows_ghosts"] = r.get("integrated_area_overbright_above_10_mm2_s", 0) > 0
    if "reactive_0ms" in systems:
        targets["reactive_0ms_restores_every_point"] = systems["reactive_0ms"]["max_drop"] < 1e-3
    out = {"benchmark": "motion", "machine": machine(), **{k: v for k, v in doc.items() if k != "study"},
           "comparison": comparison, "targets": targets}
    print(json.dumps(out, indent=1))
    return 0
