"""`shadowless bench plan`: the layout planner on the reference table (and the bust): speed and what it recovers.

Prints one JSON document:

* ``plan_seconds``: wall time to choose 25 of 100 ceiling positions (a 10 x 10
  grid over the reference rig's 1 m square, 1.4 m up), from caching every
  (candidate, hand pose) shadow to the end of the swap refinement; target <= 60 s.
* ``curve``: the planner's proxy with 1..25 projectors (greedy prefixes);
  ``knee_projectors``: the count after which one more projector improves the
  proxy by less than 5 % of the P1 -> P25 improvement (both measured with the
  same proxy, hands and samples on the reference rig's own projectors).
* ``reference``: the proxy of the paper's layouts P1 ... P25; from it
  ``dense_beats_wide_9`` (P9D < P9W) and ``centre_free_20_not_worse``
  (P20 <= P25): what the planner's own objective says about the paper's guidelines.
* ``pointwise``: :func:`planner.pointwise.search` on the same hands and candidates: whether any
  pointwise proxy (a nondecreasing weight of the drop) reproduces the study's four orderings while
  every layout of at most ``most`` projectors ranks behind P25 (``exists``; false is a proof, with
  the planner's ``small_layouts_ahead`` that rule every weighting out, and ``must_give``: the
  orderings the best weighting still breaks, by a fraction of P1's value).
* ``bust`` (not with --quick): the procedural bust with pointing hands, the same
  budget from the ceiling grid alone and from the ceiling plus walls: the area
  lit by fewer than ``k`` projectors and the proxy, and how many wall
  positions the planner takes.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from bench.machine import machine
from sim.mesh import bust
from planner.candidates import ProjectorModel, ceiling_grid, source_for, walls
from planner.evaluate import PLAN_PROXIES, Evaluator
from planner.pointwise import reference_evaluator
from planner.pointwise import search as pointwise_search
from planner.search import knee, plan
from planner.surface import (
    bust_poses,
    irradiance,
    mesh_surface,
    table_poses,
    table_surface,
)
from sim.scene import TABLE_SIZE
from studies.proxies import CHOSEN, PoseSet


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--budget", type=int, default=25, help="projectors to place (default 25)")
    parser.add_argument("--grid", type=int, default=10, help="candidate grid side (default 10: 100 positions)")
    parser.add_argument("--pitch", type=float, default=10.0, help="table sample spacing, mm (default 10)")
    parser.add_argument("--proxy", choices=PLAN_PROXIES, default=CHOSEN, help=f"the planner's objective (default {CHOSEN})")
    parser.add_argument("--bust-budget", type=int, default=12, help="projectors on the bust (default 12)")
    parser.add_argument("--bust-k", type=int, default=2, help="coverage asked of every bust point (default 2)")
    parser.add_argument("--pointwise-most", type=int, default=3, metavar="N",
                        help="the pointwise search: layouts of at most N projectors behind P25 (default 3; 0 skips it)")
    parser.add_argument("--quick", action="store_true", help="a 6x6 grid, budget 12, no bust (a smoke run)")
    parser.add_argument("--seed", type=int, default=0)


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def bust_comparison(budget: int, k: int, proxy: str) -> dict:
    surface = mesh_surface(bust(), name="bust")
    hands = bust_poses()
    model = ProjectorModel()
    out = {"hand_poses": len(hands), "samples": surface.size, "area_mm2": round(float(surface.area.sum()), 1), "budget": budget, "k": k}
    for name, cands in (("ceiling", ceiling_grid(5, 5)), ("ceiling_and_walls", ceiling_grid(5, 5) + walls(4))):
        sources = [source_for(c, surface.target, surface.corners, model) for c in cands]
        ev = Evaluator(surface, sources, irradiance(surface, sources), hands, proxy=proxy)
        t0 = time.perf_counter()
        res = plan(ev, min(budget, len(sources)), k=k)
        on_walls = [sources[i].name for i in res.chosen if sources[i].center[2] < 1399.0]
        never = float(surface.area[(ev.coverage(range(len(sources))) < k)].sum())
        out[name] = {
            "candidates": len(sources), "proxy": round(res.value, 4), "uncovered_mm2": round(res.uncovered, 1),
            "unreachable_mm2": round(never, 1), "wall_positions_chosen": len(on_walls), "walls": on_walls,
            "plan_seconds": round(time.perf_counter() - t0, 2),
        }
        _say(f"bust, {name}: {proxy} {res.value:.4g}, {res.uncovered:.0f} mm^2 lit by fewer than {k}")
    return out


def run(args: argparse.Namespace) -> int:
    budget, side, do_bust = args.budget, args.grid, not args.quick
    if args.quick:
        budget, side = 12, 6
    if not 1 <= budget <= side * side:
        raise SystemExit(f"--budget must be 1..{side * side}")
    doc: dict = {"benchmark": "plan", "machine": machine(),
                 "parameters": {"budget": budget, "candidates": side * side, "pitch_mm": args.pitch, "proxy": args.proxy, "seed": args.seed}}
    surface = table_surface(TABLE_SIZE, pitch=args.pitch)
    hands = table_poses(PoseSet(heights=(200.0,)))
    doc["parameters"]["hand_poses"] = PoseSet(heights=(200.0,)).describe()
    t0 = time.perf_counter()
    sources = [source_for(c, surface.target, surface.corners, ProjectorModel()) for c in ceiling_grid(side, side)]
    ev = Evaluator(surface, sources, irradiance(surface, sources), hands, proxy=args.proxy)
    cached = time.perf_counter() - t0
    res = plan(ev, budget, progress=_say)
    seconds = time.perf_counter() - t0
    ref_ev, subsets = reference_evaluator(surface, hands, seed=args.seed, proxy=args.proxy)  # the paper's layouts
    ref = {n: round(ref_ev.value(s), 4) for n, s in subsets.items()}
    span = ref["P1"] - ref["P25"]
    doc.update({
        "plan_seconds": round(seconds, 2),
        "cache_seconds": round(cached, 2),
        "curve": [round(v, 4) for v in res.curve],
        "value_after_swaps": round(res.value, 4),
        "swaps": res.swaps,
        "chosen": [sources[i].name for i in res.chosen],
        "reference": ref,
        "p1_to_p25_improvement": round(span, 4),
        "knee_projectors": knee(res.curve, span),
        "dense_beats_wide_9": ref["P9D"] < ref["P9W"],
        "centre_free_20_not_worse": ref["P20"] <= ref["P25"],
        "planned_vs_p25": round(res.value / ref["P25"], 3) if budget == 25 and ref["P25"] > 0 else None,
    })
    if args.pointwise_most > 0:
        t1 = time.perf_counter()
        most = min(args.pointwise_most, ev.candidates)
        found = pointwise_search(ev, ref_ev, subsets, most=most, bands=50 if args.quick else 200, progress=_say)
        doc["pointwise"] = {"most": most, "exists": found.exists, "small_layouts_ahead": found.layouts,
                            "must_give": {k: float(f"{v:.3g}") for k, v in found.must_give.items()},
                            "rounds": len(found.rounds) + (0 if found.exists else 1),  # the last, unsolvable fit counts
                            "seconds": round(time.perf_counter() - t1, 2)}
    doc["targets"] = {"plan_25_of_100_under_60_s": seconds <= 60.0 if (budget, side) == (25, 10) else None}
    if do_bust:
        doc["bust"] = bust_comparison(args.bust_budget, args.bust_k, args.proxy)
    print(json.dumps(doc, indent=1))
    return 0
