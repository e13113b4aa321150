"""`shadowless rig`: create and inspect rig directories."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from coordinator.errors import RigError
from rigctl import board_cli, user_cli
from rigctl.mpcdi import cli as mpcdi_cli
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.rig_layout import BuiltinMesh, init_from_layout
from protos import cli_types
from protos.wording import count

INIT_EXAMPLES = """\
examples:
  shadowless rig init rigs/table --grid 5x5 --resolution 1920x1080
  shadowless rig init rigs/pair --slots left,right --resolution 1280x800 --content-size 1200x600
  shadowless plan --budget 9 --layout plan.toml && shadowless rig init rigs/planned --layout plan.toml
  shadowless rig init rigs/room --layout plan.toml --resolution 320x200   # for `shadowless room --layout plan.toml`
  shadowless coverage --rig-dir rigs/planned --planned                      # the plan's coverage, no hardware

--layout FILE (what `shadowless plan` and `shadowless room --write-layout` write) gives one slot per
[[projector]] (its `slot` name, else p0, p1, ...), each at its `resolution`, the content size of its
surface at 1 px per mm (the [mesh] if any, else the [table]), and stores each slot's PLANNED pose
(its position, aim and focal length onto that surface). A planned pose is not a calibration: nodes
do not render it and transport, compensation and the other jobs still need `shadowless calibrate`,
which replaces it; `shadowless coverage --planned` reads it.
"""


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    init = sub.add_parser("init", help="create a rig directory: rig.toml with slots, and a fresh token",
                          description="Create a rig directory: rig.toml (human-editable) and a token file (0600). "
                                      "Copy the token to every node (e.g. /etc/shadowless/token).",
                          epilog=INIT_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    init.add_argument("dir", help="the rig directory to create")
    init.add_argument("--name", help="rig name, advertised over mDNS (default: the directory's name)")
    g = init.add_mutually_exclusive_group()
    g.add_argument("--grid", type=cli_types.grid, metavar="COLSxROWS", default=(5, 5),
                   help="slots r0c0… for a projector array (default 5x5)")
    g.add_argument("--slots", type=cli_types.names, metavar="A,B,...", help="explicit comma-separated slot names instead of a grid")
    g.add_argument("--layout", metavar="FILE", help="a planned layout (TOML, `shadowless plan`): its projectors' slots, "
                                                    "resolutions, content size and planned poses")
    init.add_argument("--resolution", type=cli_types.size, default=None, metavar="WxH",
                      help="projector output size (default 1920x1080; with --layout the layout's, and the planned poses "
                           "are resampled to this size)")
    init.add_argument("--content-size", type=cli_types.size, default=None, metavar="WxH",
                      help="shared image size in content px (default 1200x600: 1 px per mm on a 1200x600 mm table; with "
                           "--layout 1 px per mm of its surface)")
    init.add_argument("--latency-ms", type=cli_types.number(0, 10000, lo_open=True), default=50.0, help="frame scheduling budget (default 50)")
    init.add_argument("--force", action="store_true", help="replace an existing rig.toml (keeps the token and state)")
    show = sub.add_parser("show", help="print a rig directory's configuration and per-slot state as JSON")
    show.add_argument("dir")
    mpcdi_cli.configure_export(sub.add_parser("export", help="write a rig directory's calibration to an MPCDI archive"))
    mpcdi_cli.configure_import(sub.add_parser("import", help="read an MPCDI archive's calibration into a rig directory"))
    user_cli.configure(sub.add_parser("user", help="who may log in to the console, by name and password, and their role"))
    board_cli.configure(sub.add_parser("board", help="write a printable ChArUco board (PDF, PNG) and its JSON for calibrate"))


def _created(path: Path, what: str) -> None:
    rig_id = Rig(path, read_only=True).config.rig_id
    print(f"created rig in {path}: {what}, id {rig_id}; token in {path / 'token'}\n"
          f"on every node: copy the token to /etc/shadowless/token and set RIG={rig_id} in node.env")


def _init_from_layout(args: argparse.Namespace, builtin_mesh: BuiltinMesh | None) -> int:
    path, plan = init_from_layout(args.dir, args.layout, name=args.name, builtin_mesh=builtin_mesh,
                                  resolution=args.resolution, content_size=args.content_size,
                                  latency_ms=args.latency_ms, force=args.force)
    sizes = sorted({f"{w}x{h}" for w, h in plan.slots.values()})
    _created(path, f"{count(len(plan.slots), 'slot')} from layout {args.layout} ({', '.join(sizes)}), content "
                   f"{plan.content_size[0]}x{plan.content_size[1]}, planned poses onto the {plan.surface}")
    if plan.unpowered:
        print(f"left out, unpowered in the layout: {', '.join(plan.unpowered)} (set powered = true there to make "
              "them slots)")
    print(f"planned poses are not a calibration: the plan's coverage now, `shadowless coverage --rig-dir {path} "
          "--planned`; calibrate once the projectors hang")
    return 0


def run(args: argparse.Namespace, *, builtin_mesh: BuiltinMesh | None = None) -> int:
    """The command; ``builtin_mesh`` builds the meshes a layout may name by name (the wiring's)."""
    try:
        if args.rig_command == "init":
            if args.layout:
                return _init_from_layout(args, builtin_mesh)
            cols, rows = args.grid
            slots = args.slots or grid_slots(rows, cols)
            (width, height), (cw, ch) = args.resolution or (1920, 1080), args.content_size or (1200, 600)
            path = init_rig(args.dir, name=args.name or Path(args.dir).resolve().name, slots=slots,
                            width=width, height=height, content_width=cw, content_height=ch,
                            latency_ms=args.latency_ms, force=args.force)
            _created(path, count(len(slots), "slot"))
            return 0
        if args.rig_command == "user":
            return user_cli.run(args)
        if args.rig_command == "board":
            return board_cli.run(args)
        if args.rig_command in ("export", "import"):
            return (mpcdi_cli.run_export if args.rig_command == "export" else mpcdi_cli.run_import)(args)
        rig = Rig(args.dir, read_only=True)
        doc = {
            "name": rig.config.name, "id": rig.config.rig_id, "dir": str(rig.path),
            "content": [rig.config.content_width, rig.config.content_height],
            "slots": {n: {"size": [s.width, s.height], "revision": s.revision, "gain": s.gain,
                          "pose": s.pose.kind if s.pose else None,
                          "planned": s.planned is not None, "lut": s.lut is not None, "source": s.source}
                      for n, s in rig.slots.items()},
        }
        json.dump(doc, sys.stdout, indent=2)
        print()
        return 0
    except BrokenPipeError:       # stdout's reader has gone (`rig show | head -1`): the caller ends quietly
        raise
    except (RigError, ValueError, OSError) as exc:
        print(" ".join(f"shadowless rig: {exc}".split()), file=sys.stderr)   # one line, no traceback
        return 2
