"""`shadowless content`: add, list, remove and verify the content assets of a rig directory.

It works on the rig directory of this machine (where the coordinator runs), through
:class:`coordinator.assets.AssetStore`; uploading from a remote operator's machine over gRPC
comes in a later step.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from coordinator.assets import AssetStore
from coordinator.errors import AssetError
from protos.asset_manifest import Manifest

#: `add` shows progress on stderr when the input is at least this large
PROGRESS_MIN_BYTES = 64 << 20

DESCRIPTION = """\
Manage the content assets (stills, image sequences, videos) kept in a rig directory under
assets/: every file stored once by its SHA-256, every asset named by the SHA-256 of its manifest.
Nodes fetch assets by id ahead of playback.

This command works on the rig directory of THIS machine (--rig-dir, where the coordinator runs).
Uploading from a remote operator's machine over gRPC comes in a later step; until then, run it
on the coordinator's machine.
"""

EPILOG = """\
examples:
  shadowless content add logo.png --rig-dir rigs/table
  shadowless content add frames/ --fps 24 --name intro --rig-dir rigs/table
  shadowless content add show.mp4 --rig-dir rigs/table
  shadowless content list --rig-dir rigs/table
  shadowless content verify intro --rig-dir rigs/table     # id, id prefix (4+ hex) or name
  shadowless content rm 3fa2c1 --rig-dir rigs/table
"""


# ---------------------------------------------------------------- formatting
def human_bytes(n: int) -> str:
    """``1536`` -> ``'1.5 kB'`` (decimal units)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def asset_dict(asset_id: str, m: Manifest) -> dict:
    """One asset as JSON (what `content list --json` prints per asset)."""
    return {"id": asset_id, "kind": m.kind, "name": m.name, "frames": m.frames, "width": m.width,
            "height": m.height, "channels": m.channels, "bit_depth": m.bit_depth, "fps": m.fps,
            "duration_s": round(m.duration_s, 6), "bytes": m.total_bytes, "blobs": len(m.blobs), "extra": m.extra}


def assets_table(rows: list[tuple[str, Manifest]]) -> str:
    """The `content list` table: id prefix, kind, name, frames, size, channels x depth, fps,
    duration, bytes."""
    lines = [f"{'id':<14}{'kind':<10}{'name':<24}{'frames':>8}{'size':>12}{'depth':>8}{'fps':>9}{'duration':>10}{'bytes':>11}"]
    for aid, m in rows:
        name = m.name if len(m.name) <= 22 else m.name[:21] + "…"
        depth = f"{m.channels}x{m.bit_depth}{'f' if m.bit_depth == 32 else ''}"
        fps = "-" if m.kind == "still" else f"{m.fps:.3f}".rstrip("0").rstrip(".")
        dur = "-" if m.kind == "still" else f"{m.duration_s:.2f} s"
        lines.append(f"{aid[:12]:<14}{m.kind:<10}{name:<24}{m.frames:>8}{f'{m.width}x{m.height}':>12}{depth:>8}"
                     f"{fps:>9}{dur:>10}{human_bytes(m.total_bytes):>11}")
    if not rows:
        lines.append("(no assets; add one with `shadowless content add PATH`)")
    return "\n".join(lines)


class _Progress:
    """Prints `hashed X / Y (P%)` on stderr at most 5 times a second, for inputs >= PROGRESS_MIN_BYTES."""

    def __init__(self) -> None:
        self.last, self.shown = 0.0, False

    def __call__(self, done: int, total: int) -> None:
        if total < PROGRESS_MIN_BYTES:
            return
        now = time.monotonic()
        if now - self.last < 0.2 and done < total:
            return
        self.last, self.shown = now, True
        pct = 100.0 * done / total if total else 100.0
        sys.stderr.write(f"\rhashed {human_bytes(done)} / {human_bytes(total)} ({pct:.0f}%)")
        sys.stderr.flush()

    def end(self) -> None:
        if self.shown:
            sys.stderr.write("\n")
            self.shown = False


# ---------------------------------------------------------------- the command
def configure(p: argparse.ArgumentParser) -> None:
    p.description = DESCRIPTION
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    rig = argparse.ArgumentParser(add_help=False)
    rig.add_argument("--rig-dir", metavar="DIR", default=argparse.SUPPRESS,
                     help="the rig directory on this machine (with rig.toml; see `shadowless rig init`)")
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
    try:
        store = open_store(getattr(args, "rig_dir", None))
        action = args.content_command
        if action == "add":
            before = {aid for aid, _ in store.list()}
            progress = _Progress()
            try:
                m = store.add(args.path, name=args.name, fps=args.fps, progress=progress, note=_note)
            finally:
                progress.end()
            aid = m.asset_id
            what = f"{m.kind} {m.name!r}: {m.frames} frame(s), {m.width}x{m.height}, {m.channels} ch, {m.bit_depth}-bit"
            what += f", {m.fps:g} fps" if m.kind != "still" else ""
            state = "already stored" if aid in before else f"added ({len(m.blobs)} file(s), {human_bytes(m.total_bytes)})"
            print(f"{state}: {what}", file=sys.stderr)
            print(aid)
        elif action == "list":
            rows = store.list()
            if args.json:
                json.dump([asset_dict(aid, m) for aid, m in rows], sys.stdout, indent=2)
                print()
            else:
                print(assets_table(rows))
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
