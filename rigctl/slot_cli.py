"""`shadowless pattern` and `shadowless solo`: tools for some projectors of a running rig.

``pattern NAME [--slots S ...]`` puts a test pattern (white, grid, crosshair or colour bars, each
labelled with its slot's name) on the named projectors and black on the others; ``solo S ...``
keeps the picture on the named projectors only, the others black, and ``solo --end`` ends it. Both
hold until the next show, stop or blackout, and call the same coordinator methods as the console's
buttons (:mod:`coordinator.slot_tools`).
"""
from __future__ import annotations

import argparse
import asyncio
import sys

from coordinator.test_patterns import PATTERNS
from protos import auth
from rigctl.client import OperatorError, add_connection_args
from rigctl.rig_target import open_client

PATTERN_HELP = """\
patterns (each labelled with its slot's name):
  white      every pixel white: brightness, lamp colour, hot spots
  grid       lines every eighth of the short side, and along the edges: focus, keystone, overlaps
  crosshair  a cross through the centre inside a border: centring and the frame's extent
  bars       eight vertical colour bars (white, yellow, cyan, green, magenta, red, blue, black)

examples:
  shadowless pattern grid --rig-dir rigs/table                  # every projector
  shadowless pattern bars --slots r1c1 r1c2 --rig-dir rigs/table
  shadowless stop --rig-dir rigs/table                          # the rig's content again
"""

SOLO_HELP = """\
examples:
  shadowless solo r2c3 --rig-dir rigs/table          # only r2c3 shows the picture
  shadowless solo r2c3 r2c4 --rig-dir rigs/table     # choose again: r2c3 and r2c4
  shadowless solo --end --rig-dir rigs/table         # every projector shows it again
"""


def configure_pattern(p: argparse.ArgumentParser) -> None:
    p.description = ("Show a test pattern on some projectors (all of them without --slots), black on the others, "
                     "until the next show, stop or blackout.")
    p.epilog = PATTERN_HELP
    p.add_argument("name", choices=PATTERNS, metavar="NAME", help=f"the pattern: {', '.join(PATTERNS)}")
    p.add_argument("--slots", nargs="+", metavar="SLOT", help="the projectors that show it (default: every one)")
    add_connection_args(p)


def configure_solo(p: argparse.ArgumentParser) -> None:
    p.description = ("Only the named projectors go on showing the still on screen; the others go black, until "
                     "the next show, stop or blackout, or `solo --end`. A solo holds a still: stop a playing "
                     "show first.")
    p.epilog = SOLO_HELP
    p.add_argument("slots", nargs="*", metavar="SLOT", help="the projectors that keep the picture")
    p.add_argument("--end", action="store_true", help="end the solo: every projector shows the picture again")
    add_connection_args(p)


configure = configure_pattern


async def _run(args) -> int:
    if args.command == "solo":
        if bool(args.slots) == bool(args.end):
            raise OperatorError("name the slots to solo, or --end to end the solo (not both)")
        async with await open_client(args) as c:
            showing = await c.solo([] if args.end else args.slots)
    else:
        async with await open_client(args) as c:
            showing = await c.show_test_pattern(args.name, args.slots)
    if showing.startswith("solo ") and ": " in showing:     # "solo r0c0: <what was on screen>"
        solo, _, base = showing.partition(": ")
        showing = f"{solo}, the others black; the picture: {base}"   # not "solo r0c0: ... on every projector"
    print(f"the rig shows {showing}" if not showing.startswith("no solo") else showing)
    return 0


def run(args) -> int:
    try:
        return asyncio.run(_run(args))
    except (OperatorError, auth.TokenError) as exc:     # a refused call too (CallRefused)
        print(f"shadowless {args.command}: {exc}", file=sys.stderr)
        return 2
