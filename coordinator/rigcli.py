"""`shadowless rig`: create and inspect rig directories."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from coordinator.errors import RigError
from coordinator.mpcdi import cli as mpcdi_cli
from coordinator.rig import Rig, grid_slots, init_rig
from protos import cli_types



def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    init = sub.add_parser("init", help="create a rig directory: rig.toml with slots, and a fresh token",
                          description="Create a rig directory: rig.toml (human-editable) and a token file (0600). "
                                      "Copy the token to every node (e.g. /etc/shadowless/token).")
    init.add_argument("dir", help="the rig directory to create")
    init.add_argument("--name", help="rig name, advertised over mDNS (default: the directory's name)")
    g = init.add_mutually_exclusive_group()
    g.add_argument("--grid", type=cli_types.grid, metavar="COLSxROWS", default=(5, 5),
                   help="slots r0c0… for a projector array (default 5x5)")
    g.add_argument("--slots", type=cli_types.names, metavar="A,B,...", help="explicit comma-separated slot names instead of a grid")
    init.add_argument("--resolution", type=cli_types.size, default=(1920, 1080), metavar="WxH", help="projector output size (default 1920x1080)")
    init.add_argument("--content-size", type=cli_types.size, default=(1200, 600), metavar="WxH",
                      help="shared image size in content px (default 1200x600: 1 px per mm on a 1200x600 mm table)")
    init.add_argument("--latency-ms", type=cli_types.number(0, 10000, lo_open=True), default=50.0, help="frame scheduling budget (default 50)")
    init.add_argument("--force", action="store_true", help="replace an existing rig.toml (keeps the token and state)")
    show = sub.add_parser("show", help="print a rig directory's configuration and per-slot state as JSON")
    show.add_argument("dir")
    mpcdi_cli.configure_export(sub.add_parser("export", help="write a rig directory's calibration to an MPCDI archive"))
    mpcdi_cli.configure_import(sub.add_parser("import", help="read an MPCDI archive's calibration into a rig directory"))


def run(args: argparse.Namespace) -> int:
    try:
        if args.rig_command == "init":
            cols, rows = args.grid
            slots = args.slots or grid_slots(rows, cols)
            path = init_rig(args.dir, name=args.name or Path(args.dir).resolve().name, slots=slots,
                            width=args.resolution[0], height=args.resolution[1], content_width=args.content_size[0],
                            content_height=args.content_size[1], latency_ms=args.latency_ms, force=args.force)
            rig_id = Rig(path).config.rig_id
            print(f"created rig in {path}: {len(slots)} slots, id {rig_id}; token in {path / 'token'}\n"
                  f"on every node: copy the token to /etc/shadowless/token and set RIG={rig_id} in node.env")
            return 0
        if args.rig_command in ("export", "import"):
            return (mpcdi_cli.run_export if args.rig_command == "export" else mpcdi_cli.run_import)(args)
        rig = Rig(args.dir, read_only=True)
        doc = {
            "name": rig.config.name, "id": rig.config.rig_id, "dir": str(rig.path),
            "content": [rig.config.content_width, rig.config.content_height],
            "slots": {n: {"size": [s.width, s.height], "revision": s.revision, "gain": s.gain,
                          "pose": s.pose.kind if s.pose else None, "lut": s.lut is not None, "source": s.source}
                      for n, s in rig.slots.items()},
        }
        json.dump(doc, sys.stdout, indent=2)
        print()
        return 0
    except (RigError, ValueError, OSError) as exc:
        print(" ".join(f"shadowless rig: {exc}".split()), file=sys.stderr)   # one line, no traceback
        return 2
