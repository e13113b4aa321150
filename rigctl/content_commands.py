"""`shadowless content`: add, list, remove and verify the content assets of a rig.

On the coordinator's machine it works on the rig directory (``--rig-dir``) through
:class:`coordinator.assets.AssetStore`. From any other machine (``--coordinator HOST:PORT`` or
``--rig NAME``) it talks to the running coordinator's ContentStore service: ``add`` hashes the
files here, announces them, sends only the bytes the coordinator does not hold yet (so running
it again after a cut resumes the upload) and has the coordinator check and add them.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from coordinator.assets import AssetStore
from rigctl.client import add_connection_args
from rigctl.content_format import Progress, added_line, human_bytes, print_assets
from coordinator.errors import AssetError

DESCRIPTION = """\
Manage the content assets (stills, image sequences, videos) kept in a rig directory under
assets/: every file stored once by its SHA-256, every asset named by the SHA-256 of its manifest.
Nodes fetch assets by id ahead of playback.

With --rig-dir DIR it works on the rig directory of THIS machine (where the coordinator runs).
With --coordinator HOST:PORT (or --rig NAME, found over mDNS) it works on a running coordinator
from any machine with the rig token (--token-file): `add` uploads the files, checked by SHA-256
on arrival; an interrupted upload resumes where it stopped when the same command runs again.
`verify` runs on the coordinator's machine only.
"""

EPILOG = """\
examples:
  shadowless content add logo.png --rig-dir rigs/table
  shadowless content add frames/ --fps 24 --name intro --rig-dir rigs/table
  shadowless content add show.mp4 --rig-dir rigs/table
  shadowless content list --rig-dir rigs/table
  shadowless content verify intro --rig-dir rigs/table     # id, id prefix (4+ hex) or name
  shadowless content rm 3fa2c1 --rig-dir rigs/table
  shadowless content add show.mp4 --coordinator 10.0.0.2:7600 --token-file table.token
  shadowless content list --rig table --token-file table.token      # the coordinator found over mDNS
"""


# ---------------------------------------------------------------- the command
def configure(p: argparse.ArgumentParser) -> None:
    p.description = DESCRIPTION
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    rig = argparse.ArgumentParser(add_help=False)
    rig.add_argument("--rig-dir", metavar="DIR", default=argparse.SUPPRESS,
                     help="the rig directory on this machine (with rig.toml; see `shadowless rig init`)")
    add_connection_args(rig, rig_dir=False)   # with --coordinator or --rig: a running coordinator's store
    p.add_argument("--rig-dir", metavar="DIR", help="the rig directory on this machine (also accepted after ACTION)")
    sub = p.add_subparsers(dest="content_command", metavar="ACTION", required=True)
    add = sub.add_parser("add", parents=[rig], help="add a still, a video or a folder of images (a sequence); print its id",
                         description="Add content and print its asset id on stdout. A file is a still (.png 8/16-bit, "
                                     ".tif/.tiff, .jpg/.jpeg, .npy float32) or a video (.mp4, .mov, .mkv, .avi); a "
                                     "folder is an image sequence of its image files sorted by name. Adding the same "
                                     "content (and name) again gives the same id and stores nothing new.")
    add.add_argument("path", help="image, video or folder of images")
    add.add_argument("--name", help="the asset's name (default: the file's stem or the folder's name)")
    add.add_argument("--fps", type=float, help="a sequence's frame rate (default 30); for a video only when its "
                                               "container has none")
    ls = sub.add_parser("list", parents=[rig], help="list the assets: id, kind, name, frames, size, depth, fps, bytes")
    ls.add_argument("--json", action="store_true", help="print JSON for scripts instead of a table")
    rm = sub.add_parser("rm", parents=[rig], help="remove an asset and the stored files no other asset uses")
    rm.add_argument("id", help="asset id, unique id prefix (4+ hex digits) or unique name")
    ver = sub.add_parser("verify", parents=[rig], help="re-hash an asset's stored files; exit 1 if any is missing or corrupt")
    ver.add_argument("id", help="asset id, unique id prefix (4+ hex digits) or unique name")


def open_store(rig_dir: str | None) -> AssetStore:
    """The asset store of a rig directory (one with rig.toml)."""
    if not rig_dir:
        raise AssetError("which rig? pass --rig-dir DIR (the rig directory on this machine)")
    if not (Path(rig_dir) / "rig.toml").is_file():
        raise AssetError(f"{rig_dir} is not a rig directory (no rig.toml); create one with `shadowless rig init`")
    return AssetStore(rig_dir)


def _note(text: str) -> None:
    print(f"note: {text}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if getattr(args, "coordinator", None) or getattr(args, "rig", None):
        from rigctl.content_remote import run_remote  # lazy: gRPC, only for a remote store

        return run_remote(args)
    try:
        store = open_store(getattr(args, "rig_dir", None))
        action = args.content_command
        if action == "add":
            before = {aid for aid, _ in store.list()}
            progress = Progress()
            try:
                m = store.add(args.path, name=args.name, fps=args.fps, progress=progress, note=_note)
            finally:
                progress.end()
            print(added_line(m, m.asset_id in before), file=sys.stderr)
            print(m.asset_id)
        elif action == "list":
            print_assets(store.list(), as_json=args.json)
        elif action == "rm":
            aid = store.resolve(args.id)
            try:
                m = store.get(aid)
                label = f"{m.kind} {m.name!r}"
            except AssetError:
                label = "damaged manifest; its files stay until verified by hand"
            store.remove(aid)
            print(f"removed {aid[:12]} ({label})")
        elif action == "verify":
            aid = store.resolve(args.id)
            problems = store.verify(aid)
            for line in problems:
                print(f"{aid[:12]}: {line}")
            if problems:
                return 1
            m = store.get(aid)
            print(f"ok: {aid[:12]} ({m.kind} {m.name!r}): {len(m.blobs)} file(s), {human_bytes(m.total_bytes)} verified")
        return 0
    except AssetError as exc:
        print(f"shadowless content: {exc}", file=sys.stderr)
        return 2
