"""`shadowless plan`: choose projector positions that keep a hand's shadow least visible."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from protos import cli_types
from sim.mesh import bust
from planner.candidates import (
    ProjectorModel,
    ceiling_grid,
    from_file,
    source_for,
    walls,
)
from planner.evaluate import PLAN_PROXIES, Evaluator
from planner.output import layout_text, picture
from planner.search import knee, plan
from planner.surface import (
    bust_poses,
    irradiance,
    mesh_surface,
    table_poses,
    table_surface,
)
from sim.scene import TABLE_SIZE, load_layout
from studies.proxies import CHOSEN, PoseSet

DESCRIPTION = """\
Choose where to mount projectors: from candidate positions (a ceiling grid, walls, or a file),
pick --budget of them that minimise a sense-of-projection proxy under hands over the surface,
with every surface point lit by at least --k of them. Writes a layout the room and the coordinator
read (shadowless room --layout FILE; shadowless rig init DIR --layout FILE), a picture of the plan, and prints the proxy against the budget
(greedy: the best next projector each time; the chosen set is then refined by swaps)."""

EPILOG = f"""\
examples:
  shadowless plan                                   # 17 of a 10x10 ceiling grid over the table
  shadowless plan --budget 25 --grid 10x10 --layout rig.toml --picture rig.png
  shadowless plan --surface bust --mount ceiling+walls --budget 17 --k 3
  shadowless plan --candidates positions.csv        # one x,y,z[,name] per line, mm
  shadowless room --layout plan.toml                # the planned rig in the virtual room
  shadowless rig init rigs/planned --layout plan.toml   # its rig directory: slots, sizes, planned poses
  shadowless coverage --rig-dir rigs/planned --planned  # the plan's coverage, before any hardware

proxies (lower is better; default {CHOSEN}): {', '.join(PLAN_PROXIES)}
hands: over the table, flat at --heights over 3x3 positions and --yaws; on the bust, pointing
hands around it at 250 and 420 mm, from six directions.
"""


def _floats(text: str) -> tuple[float, ...]:
    one = cli_types.number(-10000, 10000)
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected numbers joined by commas, got {text!r}")
    return tuple(one(p) for p in parts)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    s = parser.add_argument_group("surface and hands")
    s.add_argument("--surface", choices=["table", "bust"], default="table", help="the 1200x600 mm table (the default), or the procedural bust on it")
    s.add_argument("--pitch", type=cli_types.number(2, 100), default=10.0, metavar="MM", help="table sample spacing (default 10)")
    s.add_argument("--heights", type=_floats, default=(200.0,), metavar="MM,...", help="table hands: height of the lowest point (default 200)")
    s.add_argument("--yaws", type=_floats, default=(-30.0, 0.0, 30.0), metavar="DEG,...", help="table hands: finger directions (default -30,0,30)")
    m = parser.add_argument_group("where projectors may go")
    m.add_argument("--mount", choices=["ceiling", "walls", "ceiling+walls"], default="ceiling", help="candidate positions (default ceiling)")
    m.add_argument("--grid", type=cli_types.grid, default=(10, 10), metavar="COLSxROWS", help="ceiling grid (default 10x10)")
    m.add_argument("--span", type=cli_types.pair, default=(1000.0, 1000.0), metavar="W,D", help="ceiling grid extent, mm (default 1000,1000)")
    m.add_argument("--ceiling", type=cli_types.number(100, 10000), default=1400.0, metavar="MM", help="ceiling height above the table (default 1400)")
    m.add_argument("--per-wall", type=cli_types.int_range(1, 50), default=4, metavar="N", help="wall positions across each wall, per height (default 4)")
    m.add_argument("--candidates", type=cli_types.existing_file, metavar="FILE", help="candidate positions from a file (x,y,z[,name] per line) instead of --mount")
    p = parser.add_argument_group("projector, budget, objective")
    p.add_argument("--resolution", type=cli_types.size, default=(1280, 800), metavar="WxH", help="native resolution (default 1280x800)")
    p.add_argument("--throw-ratio", type=cli_types.number(0.05, 20, lo_open=True), metavar="R", help="focal / width (default: fitted so the surface fills each image)")
    p.add_argument("--budget", type=cli_types.int_range(1, 1000), default=17, metavar="N", help="projectors to place (default 17)")
    p.add_argument("--k", type=cli_types.int_range(1, 1000), default=1, metavar="K", help="each surface point lit by at least K (default 1)")
    p.add_argument("--proxy", choices=PLAN_PROXIES, default=CHOSEN, help=f"what to minimise (default {CHOSEN})")
    o = parser.add_argument_group("outputs")
    o.add_argument("--layout", default="plan.toml", metavar="FILE", help="layout file to write (default plan.toml)")
    o.add_argument("--picture", default="plan.png", metavar="FILE", help="picture to write (default plan.png)")
    o.add_argument("--json", action="store_true", help="print one JSON document instead of the summary")


def build(args: argparse.Namespace):
    """(surface, candidates' sources, hands) from the arguments."""
    if args.surface == "table":
        surface = table_surface(TABLE_SIZE, pitch=args.pitch)
        hands = table_poses(PoseSet(heights=tuple(args.heights), yaws=tuple(args.yaws)))
    else:
        surface = mesh_surface(bust(), name="bust")
        hands = bust_poses()
    if args.candidates:
        try:
            cands = from_file(args.candidates)
        except (OSError, ValueError) as exc:
            raise SystemExit(str(exc)) from None
    else:
        cands = []
        if args.mount in ("ceiling", "ceiling+walls"):
            cands += ceiling_grid(args.grid[0], args.grid[1], span=tuple(args.span), height=args.ceiling)
        if args.mount in ("walls", "ceiling+walls"):
            cands += walls(args.per_wall)
    model = ProjectorModel(tuple(args.resolution), args.throw_ratio)
    try:
        sources = [source_for(c, surface.target, surface.corners, model) for c in cands]
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    if args.budget > len(sources):
        raise SystemExit(f"--budget {args.budget} exceeds the {len(sources)} candidate positions")
    return surface, sources, hands


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    surface, sources, hands = build(args)

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    E = irradiance(surface, sources)
    ev = Evaluator(surface, sources, E, hands, proxy=args.proxy)
    say(f"{len(sources)} candidates, {len(hands)} hand poses, {surface.size} surface samples: cached in {time.perf_counter() - t0:.1f} s")
    result = plan(ev, args.budget, k=args.k, progress=say)
    chosen = [sources[i] for i in result.chosen]
    text = layout_text(chosen, surface, table_size=TABLE_SIZE)
    Path(args.layout).write_text(text)
    load_layout(args.layout)  # what we wrote must be what the room reads
    on_walls = frozenset(i for i, s in enumerate(sources) if s.center[2] < args.ceiling - 1.0)
    picture(args.picture, surface, sources, result.chosen, result.curve, proxy=args.proxy, walls=on_walls)
    span = result.curve[0] - min(result.curve)
    doc = {
        "surface": surface.name, "candidates": len(sources), "hand_poses": len(hands), "budget": args.budget, "k": args.k, "proxy": args.proxy,
        "chosen": [{"slot": s.name, "position_mm": [round(float(v), 1) for v in s.center]} for s in chosen],
        "wall_positions_chosen": sum(1 for i in result.chosen if i in on_walls),
        "uncovered_curve_mm2": [round(v, 1) for v in result.uncovered_curve],
        "curve": [round(v, 4) for v in result.curve],
        "value": round(result.value, 4), "uncovered_mm2": round(result.uncovered, 1), "swaps": result.swaps,
        "knee_projectors": knee(result.curve, span),
        "rig_init": f"shadowless rig init DIR --layout {args.layout}",
        "layout": str(args.layout), "picture": str(args.picture), "seconds": round(time.perf_counter() - t0, 1),
    }
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(f"chosen {args.budget} of {len(sources)}: {', '.join(s.name for s in chosen)}")
    print(f"{args.proxy} by projector count: " + " ".join(f"{v:.3g}" for v in result.curve))
    if result.uncovered_curve[0] > 0:
        print(f"area lit by fewer than {args.k} (mm^2) by count: " + " ".join(f"{v:.0f}" for v in result.uncovered_curve))
    print(f"after swaps: {result.value:.4g}; area lit by fewer than {args.k}: {result.uncovered:.0f} mm^2; "
          f"flattens after {doc['knee_projectors']} projectors (one more improves by < 5 % of the curve's range)")
    if doc["wall_positions_chosen"]:
        print(f"{doc['wall_positions_chosen']} of them on walls")
    print(f"wrote {args.layout} (shadowless room --layout {args.layout}; shadowless rig init DIR --layout {args.layout}) and {args.picture}")
    return 0
