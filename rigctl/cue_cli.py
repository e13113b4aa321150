"""`shadowless cue`: the show's cue list on a running coordinator: list, add, rm, move, load, go,
back, jump.

Every subcommand talks to the rig's coordinator through its control service (the list lives in the
rig directory as cues.json, kept by the coordinator; see :mod:`coordinator.cues`); edits read the
list, change it here and send it back whole, so the coordinator validates every edit as it validates
a list from the console.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import shlex
import sys
import time
from pathlib import Path

from protos import auth
from protos.cues import KINDS, Cue, CueError, CueList
from protos.wording import ago, count
from rigctl.client import OperatorError, add_connection_args
from rigctl.rig_target import open_client

DESCRIPTION = """\
Run a show from a cue list: each cue shows a still, plays an asset, blacks out or shows a test
pattern, with an optional crossfade and auto-follow.

GO fires the next cue; back fires the one before it (a cut); jump fires any cue by its id. A cue with
--fade crossfades from what is on the projectors: every node starts the fade at the same rig instant
and mixes the two pictures frame by frame, so the projectors agree to the frame. A cue with --follow
fires the next cue that many seconds after it reached the screen; any GO, back, jump or other action
on the projectors cancels a pending follow. The list is kept in the rig directory (cues.json) with the
current cue, so a restarted coordinator shows it again. The console's cue panel edits the same list.

Targets: a still is `content` (the rig's own content, set with `shadowless show --persist`) or a still
asset of the rig's store (`shadowless content add`); an asset is any asset (a video plays as a
timeline show on every projector, its first frames mixed with what was on screen during a fade); a
pattern is white, grid, crosshair or bars (patterns cut: they are projector pixels). Going back cuts.
"""

EXAMPLES = """\
examples:
  shadowless cue add rigs/table --kind blackout --name "Preset"
  shadowless cue add rigs/table --kind still --target content --fade 2 --name "Opening"
  shadowless cue add rigs/table --kind asset --target intro.mp4 --fade 1
  shadowless cue add rigs/table --kind still --target logo --fade 3 --follow 10 --slots r0c0,r0c1
  shadowless cue list rigs/table                 # ▶ marks the current cue, → the next
  shadowless cue go rigs/table                   # fire the next cue
  shadowless cue jump rigs/table 3               # fire cue 3
  shadowless cue move rigs/table 3 1             # cue 3 becomes the first
  shadowless cue load rigs/table show.json       # replace the list ({"cues": [...]}, as `cue list --json`)
"""


def _rig_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("rig_path", nargs="?", metavar="RIG", help="the rig directory (same as --rig-dir)")
    add_connection_args(p)


def configure(p: argparse.ArgumentParser) -> None:
    p.description = DESCRIPTION
    p.epilog = EXAMPLES
    sub = p.add_subparsers(dest="cue_command", metavar="SUBCOMMAND", required=True)
    fmt = argparse.RawDescriptionHelpFormatter
    ls = sub.add_parser("list", help="the cue list, the current cue (▶) and the next (→)", formatter_class=fmt)
    _rig_arg(ls)
    ls.add_argument("--json", action="store_true", help="print the cue state as JSON (cues, current, next, ...)")
    add = sub.add_parser("add", help="add a cue (at the end, or --at a position)", formatter_class=fmt)
    _rig_arg(add)
    add.add_argument("--kind", required=True, choices=KINDS, help="what the cue shows")
    add.add_argument("--target", default="", metavar="NAME",
                     help="still: 'content' or a still asset; asset: an asset's name or id; pattern: white, grid, "
                          "crosshair or bars")
    add.add_argument("--name", default="", help="a name the operator reads (e.g. 'Act 1: opening')")
    add.add_argument("--id", default="", dest="cue_id", help="the cue's id (default: one more than the largest number)")
    add.add_argument("--fade", type=float, default=0.0, metavar="S",
                     help="crossfade from what is on screen over S seconds (default 0: a cut; patterns always cut)")
    add.add_argument("--follow", type=float, default=None, metavar="S",
                     help="fire the next cue S seconds after this one reached the screen")
    add.add_argument("--slots", default="", metavar="A,B",
                     help="only these projectors show it, the others go black (default: every projector)")
    add.add_argument("--at", type=int, default=None, metavar="N", help="insert at position N (1 = first)")
    rm = sub.add_parser("rm", help="remove a cue", formatter_class=fmt)
    _rig_arg(rm)
    rm.add_argument("id", help="the cue's id")
    mv = sub.add_parser("move", help="move a cue to another position", formatter_class=fmt)
    _rig_arg(mv)
    mv.add_argument("id", help="the cue's id")
    mv.add_argument("position", type=int, help="its new position (1 = first)")
    load = sub.add_parser("load", help="replace the list with a JSON file ({\"cues\": [...]})", formatter_class=fmt)
    _rig_arg(load)
    load.add_argument("file", help="the cue list (as `shadowless cue list --json` prints it)")
    for name, what in (("go", "fire the next cue"), ("back", "fire the cue before the current one (a cut)")):
        _rig_arg(sub.add_parser(name, help=what, formatter_class=fmt))
    jump = sub.add_parser("jump", help="fire a cue by its id (with its fade)", formatter_class=fmt)
    _rig_arg(jump)
    jump.add_argument("id", help="the cue's id")


def cue_table(state: dict, *, now: float | None = None, rig: str = "") -> str:
    """The cue list as the operator reads it: ▶ the current cue, → the next, then a summary line.
    ``rig``: the rig directory the operator named, so that the commands suggested can be pasted as
    they are (without one they name no rig: the operator reached it some other way)."""
    now = time.time() if now is None else now
    where = f" {shlex.quote(rig)}" if rig else ""
    cues = [Cue.from_json(c) for c in state.get("cues", [])]
    if not cues:
        return f"no cues yet: add one with `shadowless cue add{where or ' RIG'} --kind still --target content`"
    current, nxt = state.get("current"), state.get("next")
    rows = [("", "ID", "NAME", "KIND", "TARGET", "FADE", "FOLLOW", "SLOTS")]
    for i, c in enumerate(cues):
        mark = "▶" if i == current else "→" if i == nxt else ""
        rows.append((mark, c.id, c.name or "-", c.kind, c.target or "-", f"{c.fade_s:g} s" if c.fade_s else "cut",
                     f"{c.follow_s:g} s" if c.follow_s is not None else "-", ",".join(c.slots) or "all"))
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in rows]
    if current is not None:
        fired = state.get("fired_at")
        when = f", fired {ago(now - fired)}" if isinstance(fired, (int, float)) else ""
        fading = ", fading" if state.get("fading") else ""
        summary = f"current: cue {cues[current].id}{when}{fading}"
    else:
        summary = "no cue fired yet"
    if nxt is not None:
        follow = state.get("follow_at")
        then = f" (auto-follow in {max(0.0, follow - now):.1f} s)" if isinstance(follow, (int, float)) else ""
        summary += f"; next: cue {cues[nxt].id}{then} (`shadowless cue go{where}`)"
    else:
        summary += "; that was the last cue"
    return "\n".join(lines + ["", f"{count(len(cues), 'cue')}; {summary}"])


def _edited(state: dict, args) -> tuple[CueList, str]:
    """The list after the edit the arguments ask for, and what to say (CueError for a bad one)."""
    cues = CueList.from_json(state)
    items = list(cues.cues)
    sub = args.cue_command
    if sub == "add":
        slots = tuple(s for s in args.slots.replace(",", " ").split() if s)
        cue = Cue(id=args.cue_id or cues.next_id(), name=args.name, kind=args.kind, target=args.target,
                  fade_s=args.fade, follow_s=args.follow, slots=slots)
        cue.validate()
        at = len(items) if args.at is None else args.at - 1
        if not 0 <= at <= len(items):
            raise CueError(f"--at must be 1..{len(items) + 1}, got {args.at}")
        items.insert(at, cue)
        return CueList(tuple(items)), f"added cue {cue.label} at position {at + 1}"
    if sub == "rm":
        i = cues.index(args.id)
        gone = items.pop(i)
        return CueList(tuple(items)), f"removed cue {gone.label}"
    if sub == "move":
        i = cues.index(args.id)
        if not 1 <= args.position <= len(items):
            raise CueError(f"the position must be 1..{len(items)}, got {args.position}")
        cue = items.pop(i)
        items.insert(args.position - 1, cue)
        return CueList(tuple(items)), f"moved cue {cue.label} to position {args.position}"
    path = Path(args.file)
    try:
        loaded = CueList.loads(path.read_text())
    except OSError as exc:
        raise CueError(f"cannot read {path}: {exc.strerror or exc}") from None
    loaded.validate()
    return loaded, f"loaded {count(len(loaded), 'cue')} from {path}"


async def _run(args) -> int:
    if args.rig_path and not args.rig_dir:
        args.rig_dir = args.rig_path
    async with await open_client(args) as c:
        sub = args.cue_command
        if sub == "list":
            state, _ = await c.cues()
            print(json.dumps(state, indent=1) if args.json else cue_table(state, rig=args.rig_dir or ""))
            return 0
        if sub in ("add", "rm", "move", "load"):
            state, _ = await c.cues()
            new, said = _edited(state, args)
            state, _ = await c.set_cues(json.dumps(new.to_json()))
            print(said)
            print(cue_table(state, rig=args.rig_dir or ""))
            return 0
        state, result = await c.fire_cue("jump" if sub == "jump" else sub, getattr(args, "id", "") or "")
        print(result)
        return 0


def run(args) -> int:
    try:
        return asyncio.run(_run(args))
    except (OperatorError, auth.TokenError, CueError) as exc:     # a refused call too (CallRefused)
        print(f"shadowless cue {args.cue_command}: {exc}", file=sys.stderr)
        return 2
