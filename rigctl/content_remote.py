"""`shadowless content … --coordinator HOST:PORT`: the rig's assets from an operator's machine.

``add`` picks the files the way the store does (a file; or a folder's images sorted by name,
:func:`coordinator.asset_probe.sequence_files`), hashes them here, announces them
(:meth:`rigctl.link.Client.begin_upload`), sends each file from the offset the
coordinator already holds, in 1 MiB chunks read in a worker thread, and asks the coordinator
to check the hashes and add the asset. A cut (Ctrl-C, a dropped link, a restarted coordinator)
loses nothing: the same command run again announces the same files, gets the same upload
back and sends only what is missing.
"""
from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import AsyncIterator

from coordinator.asset_probe import sequence_files
from coordinator.assets import copy_hashing
from rigctl.client import CallRefused, OperatorError
from rigctl.rig_target import open_client
from rigctl.content_format import Progress, added_line, human_bytes, print_assets
from coordinator.errors import AssetError, OPERATOR_ERRORS

#: bytes per UploadFile message (the coordinator's limit)
CHUNK_BYTES = 1 << 20


def upload_files(path: str | Path) -> list[Path]:
    """The files ``content add PATH`` uploads: a file, or a folder's image sequence in order."""
    src = Path(path)
    if src.is_dir():
        return sequence_files(src, note=lambda text: print(f"note: {text}", file=sys.stderr))
    if src.is_file():
        return [src]
    raise AssetError(f"{src}: no such file or folder")


def hash_files(files: list[Path]) -> list[tuple[str, int, str]]:
    """``(name, size, sha256)`` of each file, with progress on stderr for large inputs."""
    total = sum(f.stat().st_size for f in files)
    progress, done, out = Progress("hashed"), 0, []
    try:
        for f in files:
            def on_chunk(n: int) -> None:
                nonlocal done
                done += n
                progress(done, total)

            with open(f, "rb") as src:
                digest, size = copy_hashing(src, None, on_chunk=on_chunk)
            out.append((f.name, size, digest))
    finally:
        progress.end()
    return out


async def _chunks(path: Path, offset: int, on_bytes) -> AsyncIterator[bytes]:
    with open(path, "rb") as src:
        src.seek(offset)
        while data := await asyncio.to_thread(src.read, CHUNK_BYTES):
            on_bytes(len(data))
            yield data


async def upload(c, path: str | Path, *, name: str | None, fps: float | None):
    """Upload ``path`` to the coordinator's store: ``(manifest, existed, notes, bytes sent)``."""
    files = upload_files(path)
    specs = hash_files(files)
    uid, have = await c.begin_upload(specs)
    total, held = sum(s for _, s, _ in specs), sum(have)
    if held:
        print(f"resuming upload {uid[:12]}: the coordinator holds {human_bytes(held)} of {human_bytes(total)}",
              file=sys.stderr)
    progress, sent = Progress("uploaded", rate=True), [0]

    def on_bytes(n: int) -> None:
        sent[0] += n
        progress(held + sent[0], total, start=held)

    try:
        for i, (f, (_, size, _)) in enumerate(zip(files, specs)):
            if have[i] < size:
                have = await c.upload_file(uid, i, have[i], _chunks(f, have[i], on_bytes))
    finally:
        progress.end()
    default = Path(path).name if Path(path).is_dir() else ""
    m, existed, notes = await c.finish_upload(uid, name=name or default, fps=fps or 0.0)
    return m, existed, notes, sent[0]


async def _run(args: argparse.Namespace) -> int:
    action = args.content_command
    if action == "verify":
        raise OperatorError("verify re-reads the stored files: run it on the coordinator's machine with --rig-dir")
    async with await open_client(args) as c:
        if action == "add":
            m, existed, notes, sent = await upload(c, args.path, name=args.name, fps=args.fps)
            for text in notes:
                print(f"note: {text}", file=sys.stderr)
            print(f"{added_line(m, existed)} (sent {human_bytes(sent)})", file=sys.stderr)
            print(m.asset_id)
        elif action == "list":
            print_assets(await c.list_assets(), as_json=args.json)
        elif action == "rm":
            aid, m = await c.remove_asset(args.id)
            label = f"{m.kind} {m.name!r}" if m is not None else "damaged manifest"
            print(f"removed {aid[:12]} ({label})")
    return 0


def run_remote(args: argparse.Namespace) -> int:
    try:
        return asyncio.run(_run(args))
    except CallRefused as exc:
        print(f"shadowless content: the coordinator refused: {exc}", file=sys.stderr)
        return 2
    except (*OPERATOR_ERRORS, OSError) as exc:
        print(f"shadowless content: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\nshadowless content: interrupted; run the same command again to resume the upload", file=sys.stderr)
        return 130
