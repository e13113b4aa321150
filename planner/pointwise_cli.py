"""`shadowless study pointwise`: is there a pointwise proxy that reproduces the study and lets the planner flatten late?"""
from __future__ import annotations

import argparse
import json
import sys
import time

from protos import cli_types
from planner.candidates import ProjectorModel, ceiling_grid, source_for
from planner.evaluate import Evaluator
from planner.pointwise import reference_evaluator, search
from planner.surface import irradiance, table_poses, table_surface
from sim.scene import TABLE_SIZE
from studies.proxies import PoseSet

DESCRIPTION = """\
Search every pointwise proxy at once: any nondecreasing weight of a table point's light drop, summed
over the area and averaged over hands (umbra area, penumbra area, shadow_mm2, area above t, powers
of the drop are all such proxies). A linear programme finds weights that reproduce the paper's four
orderings of its layouts (P1 worst; P9D before P9W; P17, P20, P25 alike; P20 not worse than P25);
the planner then looks for layouts of at most --most projectors, from a ceiling grid, that the
weights rank ahead of P25; each it finds becomes one more constraint, and the programme is solved
again. It ends with weights under which no such small layout beats P25, or with the proof that no
weights exist: then no pointwise proxy can both reproduce the study and tell an operator that a few
projectors are worse than 25, and the planner needs a proxy of another kind. With the proof comes
what must give: the ordering (or the small layouts) that the best weighting still breaks, and by how
much of P1's value."""

EPILOG = """\
examples:
  shadowless study pointwise                 # at most 3 projectors, 10x10 ceiling grid, 200 drop bands
  shadowless study pointwise --most 2        # a weaker demand: only one or two projectors behind P25
  shadowless study pointwise --quick --json  # a 6x6 grid, 50 bands: a smoke run in seconds

The world is the planner's (shadowless plan): the table sampled every --pitch mm, flat hands at 200 mm
over 3x3 positions and three finger directions; the reference rig's layouts on the same samples.
"""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--most", type=cli_types.int_range(1, 25), default=3, metavar="N",
                        help="layouts of at most N projectors must rank behind P25 (default 3)")
    parser.add_argument("--grid", type=cli_types.int_range(2, 20), default=10, metavar="N", help="N x N ceiling candidates (default 10)")
    parser.add_argument("--pitch", type=cli_types.number(2, 100), default=10.0, metavar="MM", help="table sample spacing (default 10)")
    parser.add_argument("--bands", type=cli_types.int_range(2, 2000), default=200, metavar="B",
                        help="drop bands of equal width: the weight function's resolution (default 200)")
    parser.add_argument("--margin", type=cli_types.number(0, 0.5), default=1e-3, metavar="F",
                        help="strict orderings must hold by F x P1's value (default 0.001)")
    parser.add_argument("--tolerance", type=cli_types.number(0, 1), default=0.1, metavar="F", help="'alike' = within F of |P1 - P25| (default 0.1)")
    parser.add_argument("--rounds", type=cli_types.int_range(1, 200), default=20, metavar="N", help="at most N fits (default 20)")
    parser.add_argument("--quick", action="store_true", help="a 6x6 grid and 50 bands (a smoke run)")
    parser.add_argument("--seed", type=int, default=0, help="unit-to-unit variation of the reference rig (default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of the summary")


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _rounds(out) -> str:
    n = len(out.rounds) + (0 if out.exists else 1)  # the last, unsolvable fit is a round too
    return f"{n} round{'s' if n != 1 else ''}"


def run(args: argparse.Namespace) -> int:
    side, bands = (6, 50) if args.quick else (args.grid, args.bands)
    t0 = time.perf_counter()
    surface = table_surface(TABLE_SIZE, pitch=args.pitch)
    poses = PoseSet(heights=(200.0,))
    hands = table_poses(poses)
    sources = [source_for(c, surface.target, surface.corners, ProjectorModel()) for c in ceiling_grid(side, side)]
    ev = Evaluator(surface, sources, irradiance(surface, sources), hands)
    ref_ev, subsets = reference_evaluator(surface, hands, seed=args.seed)
    out = search(ev, ref_ev, subsets, most=args.most, bands=bands, rounds=args.rounds, tolerance=args.tolerance,
                 margin=args.margin, progress=_say)
    w = out.weights
    doc = {
        "most": args.most, "candidates": len(sources), "bands": bands, "margin": args.margin, "tolerance": args.tolerance,
        "hand_poses": poses.describe(), "pitch_mm": args.pitch,
        "exists": out.exists,
        "small_layouts_ahead": out.layouts,
        "must_give": {k: float(f"{v:.3g}") for k, v in out.must_give.items()},
        "rounds": out.rounds,
        "weights": None if w is None else {f"{d:g}": round(w.at(d), 4) for d in (0.01, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.0)},
        "seconds": round(time.perf_counter() - t0, 1),
    }
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    if w is None:
        print(f"No pointwise proxy reproduces the four orderings while ranking every layout of at most {args.most} "
              f"projectors behind P25: the linear programme has no solution with these {len(out.layouts)} layouts, "
              f"found by the planner ({_rounds(out)}):")
        for layout in out.layouts:
            print(f"  {len(layout):>2}: {' '.join(layout)}")
        print("The least any weighting must give (the elastic programme), as a fraction of P1's value:")
        for name, v in out.must_give.items():
            print(f"  {name}: {100 * v:.3g} %")
    else:
        print(f"These weights reproduce the four orderings, and the planner finds no layout of at most {args.most} "
              f"projectors ahead of P25 ({_rounds(out)}):")
        print("  drop   " + " ".join(f"{k:>6}" for k in doc["weights"]))
        print("  weight " + " ".join(f"{v:>6.3g}" for v in doc["weights"].values()))
    print(f"{len(sources)} candidates, {len(hands)} hand poses, {bands} drop bands; {doc['seconds']} s", file=sys.stderr)
    return 0
