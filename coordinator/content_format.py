"""How `shadowless content` shows assets and progress: tables, JSON, sizes, progress lines
(shared by the local commands, :mod:`coordinator.content_commands`, and the remote ones,
:mod:`coordinator.content_remote`)."""
from __future__ import annotations

import json
import sys
import time

from protos.asset_manifest import Manifest

#: progress is shown on stderr when the input is at least this large
PROGRESS_MIN_BYTES = 64 << 20


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


def added_line(m: Manifest, existed: bool) -> str:
    """What `content add` says about the asset it added (or found already stored)."""
    what = f"{m.kind} {m.name!r}: {m.frames} frame(s), {m.width}x{m.height}, {m.channels} ch, {m.bit_depth}-bit"
    what += f", {m.fps:g} fps" if m.kind != "still" else ""
    state = "already stored" if existed else f"added ({len(m.blobs)} file(s), {human_bytes(m.total_bytes)})"
    return f"{state}: {what}"


class Progress:
    """Prints `hashed X / Y (P%)` (or another verb, with the rate) on stderr at most 5 times a
    second, for inputs >= PROGRESS_MIN_BYTES."""

    def __init__(self, verb: str = "hashed", *, rate: bool = False) -> None:
        self.verb, self.rate = verb, rate
        self.last, self.shown, self.t0 = 0.0, False, time.monotonic()

    def __call__(self, done: int, total: int, *, start: int = 0) -> None:
        if total < PROGRESS_MIN_BYTES:
            return
        now = time.monotonic()
        if now - self.last < 0.2 and done < total:
            return
        self.last, self.shown = now, True
        pct = 100.0 * done / total if total else 100.0
        speed = ""
        if self.rate and now > self.t0 and done > start:
            speed = f" at {human_bytes(int((done - start) / (now - self.t0)))}/s"
        sys.stderr.write(f"\r{self.verb} {human_bytes(done)} / {human_bytes(total)} ({pct:.0f}%){speed}  ")
        sys.stderr.flush()

    def end(self) -> None:
        if self.shown:
            sys.stderr.write("\n")
            self.shown = False


def print_assets(rows: list[tuple[str, Manifest]], *, as_json: bool) -> None:
    """`content list`: the table, or JSON for scripts, on stdout."""
    if as_json:
        json.dump([asset_dict(aid, m) for aid, m in rows], sys.stdout, indent=2)
        print()
    else:
        print(assets_table(rows))
