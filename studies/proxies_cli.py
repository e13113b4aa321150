"""`shadowless study proxies`: sense-of-projection proxies of the paper's layouts, and which orderings each reproduces."""
from __future__ import annotations

import argparse
import json
import sys
import time

from protos import cli_types
from sim.scene import SUBSETS, TABLE_SIZE, reference_scene
from studies.proxies import (
    CHOSEN,
    ORDERINGS,
    PROXIES,
    QUICK,
    UMBRA_WEIGHT,
    WORKSPACE,
    PoseSet,
    Viewing,
    evaluate_subsets,
    ordering_table,
    umbra_weight_interval,
)
from sim.sop_shadows import Source

DESCRIPTION = """\
Sense-of-projection (SoP) proxies of the paper's layouts (P1, P9D, P9W, P13, P17, P20, P25 of the
5x5 reference rig) under flat hands over the table, and which of the paper's study orderings each
proxy reproduces: P1 worst; P9D better than P9W; P17, P20, P25 alike; P20 not worse than P25.
Every proxy is 'lower is better'; each is the mean over the hand poses."""

EPILOG = """\
examples:
  shadowless study proxies                      # 81 poses: 3x3 positions, heights 100,200,300, yaws -30,0,30
  shadowless study proxies --quick              # 2 positions, 2 yaws: a smoke run in seconds
  shadowless study proxies --heights 200 --yaws 0 --json > proxies.json
  shadowless study proxies --pitch 0.25 --edge-sigma 0.5   # finer edges (4x the work)

the proxies:
""" + "\n".join(f"  {k:<18} {v}" for k, v in PROXIES.items()) + f"""

the one this project plans with: {CHOSEN} (see `shadowless plan --help`).
"""


def _floats(lo: float, hi: float):
    one = cli_types.number(lo, hi)

    def parse(text: str) -> tuple[float, ...]:
        parts = [p for p in text.split(",") if p.strip()]
        if not parts:
            raise argparse.ArgumentTypeError(f"expected numbers joined by commas, got {text!r}")
        return tuple(one(p.strip()) for p in parts)

    return parse


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    g = parser.add_argument_group("hand poses (every combination)")
    g.add_argument("--xs", type=_floats(-600, 600), default=WORKSPACE.xs, metavar="X,...", help="hand x positions, table mm (default -300,0,300)")
    g.add_argument("--ys", type=_floats(-300, 300), default=WORKSPACE.ys, metavar="Y,...", help="hand y positions, table mm (default -150,0,150)")
    g.add_argument("--heights", type=_floats(0, 1000), default=WORKSPACE.heights, metavar="MM,...", help="height of the hand's lowest point (default 100,200,300)")
    g.add_argument("--yaws", type=_floats(-180, 180), default=WORKSPACE.yaws, metavar="DEG,...", help="finger direction from +y (default -30,0,30)")
    g.add_argument("--quick", action="store_true", help="a small pose set (2 positions x 2 yaws at 200 mm) for a smoke run")
    v = parser.add_argument_group("viewing and sampling")
    v.add_argument("--distance", type=cli_types.number(100, 5000), default=Viewing.distance_mm, metavar="MM", help="viewing distance (default 700)")
    v.add_argument("--edge-sigma", type=cli_types.number(0.05, 20), default=Viewing.edge_sigma_mm, metavar="MM", help="blur before the edge gradient (default 1)")
    v.add_argument("--pitch", type=cli_types.number(0.05, 10), default=Viewing.pitch_mm, metavar="MM", help="shadow raster pitch (default 0.5; at most half the blur)")
    v.add_argument("--tolerance", type=cli_types.number(0, 1), default=0.1, metavar="F", help="'alike' = within F of the P1-P25 range (default 0.1)")
    v.add_argument("--seed", type=int, default=0, help="unit-to-unit variation of the reference rig (default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of the table")


def run(args: argparse.Namespace) -> int:
    if args.pitch > args.edge_sigma / 2:
        raise SystemExit(f"--pitch {args.pitch} mm must be at most half of --edge-sigma {args.edge_sigma} mm")
    poses = QUICK if args.quick else PoseSet(tuple(args.xs), tuple(args.ys), tuple(args.heights), tuple(args.yaws))
    viewing = Viewing(distance_mm=args.distance, edge_sigma_mm=args.edge_sigma, pitch_mm=args.pitch)
    scene = reference_scene(seed=args.seed)
    sources = {p.slot: Source.from_spec(p) for p in scene.projectors}
    t0 = time.perf_counter()

    def progress(done: int, total: int) -> None:
        print(f"\rposes {done}/{total}", end="" if done < total else "\n", file=sys.stderr, flush=True)

    results = evaluate_subsets(sources, SUBSETS, table_size=TABLE_SIZE, poses=poses, viewing=viewing, progress=progress)
    table = ordering_table(results, tolerance=args.tolerance)
    interval = umbra_weight_interval(results, tolerance=args.tolerance)
    doc = {
        "poses": poses.describe(),
        "viewing": {"distance_mm": viewing.distance_mm, "acuity_arcmin": viewing.acuity_arcmin, "mm_per_arcmin": round(viewing.mm_per_arcmin, 4),
                    "edge_sigma_mm": viewing.edge_sigma_mm, "pitch_mm": viewing.pitch_mm},
        "tolerance": args.tolerance,
        "proxies": {name: {p: round(v, 4) for p, v in r.items()} for name, r in results.items()},
        "orderings": table,
        "umbra_weight_interval": None if interval is None else [round(v, 3) for v in interval],
        "chosen": CHOSEN,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    names = list(results)
    print(f"{'proxy (lower is better)':<20}" + "".join(f"{n:>10}" for n in names))
    for p in PROXIES:
        print(f"{p:<20}" + "".join(f"{results[n][p]:>10.4g}" for n in names))
    print()
    print(f"{'reproduces':<20}" + "".join(f"{k:>24}" for k in ORDERINGS))
    for p in PROXIES:
        mark = " <- chosen" if p == CHOSEN else ""
        print(f"{p:<20}" + "".join(f"{'yes' if table[p][k] else 'no':>24}" for k in ORDERINGS) + mark)
    print("\npenumbra + w x umbra reproduces all four for " + ("no w" if interval is None else
          f"w from {interval[0]:.3g} to {interval[1]:.3g}") + f" (shadow_mm2: w = {UMBRA_WEIGHT:g})")
    print(f"\n{doc['poses']['count']} poses, {doc['seconds']} s; 'alike' = within {args.tolerance:g} of |P1 - P25|", file=sys.stderr)
    return 0
