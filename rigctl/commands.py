"""Operator commands: `shadowless status`, `show`, `play`, `configure`, and the timeline show
(`shadowless play ASSET`, `shadowless show pause|resume|seek FRAME|stop`).

They talk to a running coordinator through :class:`rigctl.link.Client`, after the
same rig-token handshake the nodes use, and print tables (or JSON for scripts).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import signal
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
from rich.text import Text

from coordinator.api import NodeState, NodeStatus, PlayResult, PlaySettings, RigStatus, ShowState, SyncSummary
from rigctl.blend_status import blend_dict, blend_lines
from rigctl.client import OperatorError, add_connection_args
from rigctl.content_format import operator_table, rendered
from coordinator.errors import RigError
from coordinator.float_range import check_float_range
from coordinator.unposed import unposed_warning
from coordinator.image_decode import ImageRefused, drop_alpha, read_image_file
from rigctl.job_command import run_job
from rigctl.rig_target import open_client
from coordinator.schema import read_npy, validate_lut
from protos import auth, cli_types
from protos.wording import ago, duration, wall_time, count
from protos.mesh_files import MeshFileError, read_mesh
from protos.version import MAX_REQUEST_BYTES


# ---------------------------------------------------------------- formatting
def _num(x: float) -> float | None:
    return None if math.isnan(x) else round(x, 4)


def sync_dict(s: SyncSummary) -> dict:
    """Swap figures as JSON (NaN as null)."""
    return {"frames": s.frames, "skew_p50_ms": _num(s.skew_p50_ms), "skew_p99_ms": _num(s.skew_p99_ms),
            "skew_max_ms": _num(s.skew_max_ms), "skew_source": s.skew_source,
            "clock_error_p99_ms": _num(s.clock_error_p99_ms), "late": s.frames_late, "dropped": s.frames_dropped,
            "out_of_order": s.out_of_order}


def assets_dict(n: NodeStatus) -> dict:
    """A node's readiness as JSON: counts, bytes, the percentage of the bytes it holds (null when
    nothing is wanted) and one item per wanted asset."""
    pct = None if not n.asset_bytes_total else round(100.0 * n.asset_bytes_have / n.asset_bytes_total, 1)
    if n.assets_wanted and not n.asset_bytes_total:
        pct = 100.0 if n.assets_ready == n.assets_wanted else 0.0
    return {"wanted": n.assets_wanted, "ready": n.assets_ready, "bytes_have": n.asset_bytes_have,
            "bytes_total": n.asset_bytes_total, "percent": pct,
            "items": [{"id": a.asset_id, "name": a.name, "ready": a.ready, "have": a.have_bytes, "total": a.total_bytes,
                       "ready_age_ms": _num(a.ready_age_ms), **({"error": a.error} if a.error else {})}
                      for a in n.assets]}


def assets_cell(a: dict) -> str:
    """The status table's readiness column: ``2/3 41%`` (``-`` when nothing is wanted; ``!`` when
    the node gave up on an asset)."""
    if not a["wanted"]:
        return "-"
    failed = "!" if any("error" in i for i in a["items"]) else ""
    pct = 100 if a["ready"] == a["wanted"] else min(99, int(a["percent"] or 0))   # 100 % only when all are ready
    return f"{a['ready']}/{a['wanted']} {pct}%{failed}"


def clock_current(n: NodeStatus) -> bool:
    """Whether a node's clock figures (offset, drift, round trip, error) are today's: it is joined
    or live and made a clock exchange. A lost or departed node's are its last report's, and an
    expected slot has none: both are shown as none (``-``, null), not as figures that read current.
    (The console's node table keeps the same rule: :func:`coordinator.console.live.snapshot`.)"""
    return n.state in (NodeState.LIVE, NodeState.JOINED) and n.clock_rtt_ms > 0


def status_dict(st: RigStatus, *, now: float | None = None) -> dict:
    """The rig's status as JSON (what `shadowless status --json` prints). A slot without a joined
    or live node carries the newest refusal of a node claiming it (``refusal``): why it is not there.
    ``now``: the unix time ages count to (default: this machine's clock): the blend's, and each node's
    last swap as a unix time (``last_swap_at``; its frame id is ``last_swap_frame``). A node's clock
    figures are null unless they are current (:func:`clock_current`); ``last_seen_age_ms`` is how
    long ago its last report came (null for a slot no node ever joined)."""
    num = _num
    clock_now = time.time() if now is None else now
    refusals = [{"peer": r.peer, "slot": r.slot, "reason": r.reason, "age_s": round(r.age_s, 1), "count": r.count}
                for r in st.refusals]
    refused: dict[str, dict] = {}
    for r in refusals:                       # newest first
        refused.setdefault(r["slot"], r)
    adm = st.admission

    return {
        "rig": {"name": st.rig_name, "id": st.rig_id, "instance": st.instance_id, "dir": st.rig_dir,
                "protocol": st.protocol_version, "uptime_s": round(st.uptime_s, 1), "showing": st.showing,
                "latency_budget_ms": st.latency_budget_ms, "coordinator_cpu_s": round(st.cpu_s, 3)},
        "nodes": [{
            "slot": n.slot, "state": n.state.value, "host": n.hostname, "pid": n.pid,
            **_clock_dict(n),
            "last_seen_age_ms": num(n.last_seen_age_ms) if n.state != NodeState.EXPECTED else None,
            "last_swap_frame": n.last_swap_frame, "last_swap_age_ms": num(n.last_swap_age_ms),
            "last_swap_at": (None if math.isnan(n.last_swap_age_ms) or not n.last_swap_frame
                             else round(clock_now - n.last_swap_age_ms / 1e3, 3)),
            "live_age_ms": num(n.live_age_ms),
            "shown": n.frames_shown, "late": n.frames_late, "dropped": n.frames_dropped,
            "pose": n.pose_kind, "revision": n.assignment_revision, "joins": n.joins, "assets": assets_dict(n),
            "software": n.software_version, "output": n.output, "gl": n.gl,
            "decoder": (f"{n.decoder} ({n.decoder_note})" if n.decoder_note else n.decoder) or None,
            "assignment_refused": n.assignment_refused or None,
            "show": {"state": n.show.state.value, "revision": n.show.revision, "last_frame": n.show.last_frame,
                     "shown": n.show.frames_shown, "missed": n.show.frames_late, "alone_ms": round(n.show.alone_ms)},
            "refusal": refused.get(n.slot) if n.state.value in ("expected", "lost") else None,
            "left": n.left or None,        # lost because it stopped on purpose: why (its goodbye)
        } for n in st.nodes],
        "sync": sync_dict(st.sync),
        "show": show_dict(st.show),
        "sent": {"frame_packets": st.frame_packets_sent, "frame_bytes": st.frame_bytes_sent,
                 "show_updates": st.show_updates_sent, "show_bytes": st.show_bytes_sent},
        "refusals": refusals,
        "console": st.console,
        "blend": blend_dict(st.blend, now=clock_now),
        "before_auth": {"in_flight_calls": adm.in_flight_calls, "in_flight_bytes": adm.in_flight_bytes,
                        "peak_bytes": adm.peak_bytes, "admitted": adm.admitted, "refused": adm.refused,
                        "malformed": adm.malformed, "max_calls": adm.max_calls, "max_bytes": adm.max_bytes,
                        "max_calls_per_address": adm.max_calls_per_address,
                        "max_bytes_per_address": adm.max_bytes_per_address, "waited": adm.waited},
    }


def _clock_dict(n: NodeStatus) -> dict:
    """A node's clock figures as JSON: null when they are not current (:func:`clock_current`)."""
    if not clock_current(n):
        return {"clock_offset_ms": None, "drift_ppm": None, "rtt_ms": None, "clock_error_ms": None}
    return {"clock_offset_ms": round(n.clock_offset_ms, 3), "drift_ppm": round(n.clock_drift_ppm, 2),
            "rtt_ms": round(n.clock_rtt_ms, 3), "clock_error_ms": _num(n.clock_error_ms)}


def show_dict(s: ShowState) -> dict:
    """The timeline show as JSON."""
    d = asdict(s)
    d["fps"] = round(s.fps, 6)
    return d


def show_line(s: ShowState) -> str:
    """One line about the timeline show."""
    if s.state == "none":
        return "no show"
    what = f"asset {s.name or s.asset_id[:12]} ({s.asset_id[:12]})"
    frame = f" frame {s.frame}/{s.frames}" if s.frame >= 0 else ""
    return (f"show: {what} {s.state}{frame} at {s.fps:.3f} fps{', looping' if s.loop else ''}, revision {s.revision}")


def show_cell(s: dict) -> str:
    """A node's own account of the show, in a few characters: its state and its last frame."""
    if s["state"] == "none":
        return "-"
    return f"{s['state']} {s['last_frame']}" if s["last_frame"] >= 0 else s["state"]


def last_swap_cell(n: dict, *, now: float | None = None) -> str:
    """When a node last swapped a frame in, for people: ``frame 123 at 14:02:03, 0.2 s ago`` (the
    frame of the show it follows, when it follows one; a streamed frame's id is a number for
    machines and stays in the JSON), ``at 14:02:03, 0.2 s ago``, or ``-`` when it never swapped."""
    show = n.get("show") or {}
    frame = f"frame {show['last_frame']}" if show.get("state", "none") != "none" and show.get("last_frame", -1) >= 0 else ""
    at = n.get("last_swap_at")
    if at is None:
        return frame or "-"
    now = time.time() if now is None else now
    return f"{frame + ' ' if frame else ''}at {wall_time(at, now=now)}, {ago(max(0.0, now - at))}"


#: the colour of a node's state on a terminal (others: yellow)
STATE_STYLES = {"live": "green", "lost": "red", "left": "red", "refused": "red"}


def _grouped(nodes: list[dict], key: str, verb: str) -> list[str]:
    """One line per distinct value of ``key`` among the nodes that reported one: which slots
    render with which GL, run which version (a rig should show one line of each)."""
    groups: dict[str, list[str]] = {}
    for n in nodes:
        if n.get(key):
            groups.setdefault(n[key], []).append(n["slot"])
    out = []
    for value, slots in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        if len(slots) == len(nodes):
            out.append(f"every node {verb} {value}")
        else:
            out.append(f"{verb} {value}: {', '.join(slots[:8])}{' …' if len(slots) > 8 else ''} ({len(slots)})")
    return out


def status_table(d: dict, *, tty: bool = False) -> str:
    """`shadowless status` as text: the rig, a table of its nodes (their states coloured for a
    terminal, ``tty``), then outages, failed assets, sync figures and refusals."""
    r = d["rig"]
    lines = [f"rig {r['name']} ({r['id']})  instance {r['instance']}  up {duration(r['uptime_s'])}  showing: {r['showing']}"]
    t = operator_table("slot", "state", "host", ">offset ms", ">drift ppm", ">rtt ms", "last swap", ">shown", ">late",
                       ">drop", "pose", "show", "assets")
    for n in d["nodes"]:
        state = "refused" if n.get("refusal") else "left" if n.get("left") else n["state"]
        clocked = n["rtt_ms"] is not None          # else none yet, or lost: no figures, not zeros nor old ones
        t.add_row(n["slot"], Text(state, style=STATE_STYLES.get(state, "yellow")), n["host"] or "-",
                  f"{round(n['clock_offset_ms'], 3) or 0.0:.3f}" if clocked else "-",    # no "-0.0"
                  f"{round(n['drift_ppm'], 1) or 0.0:.1f}" if clocked else "-",
                  f"{n['rtt_ms']:.3f}" if clocked else "-",
                  last_swap_cell(n), str(n["shown"]), str(n["late"]), str(n["dropped"]), n["pose"],
                  show_cell(n["show"]), assets_cell(n["assets"]))
    lines.append(rendered(t, tty=tty))
    lines += _grouped(d["nodes"], "gl", "renders with") + _grouped(d["nodes"], "decoder", "decodes video with")
    lines += _grouped(d["nodes"], "software", "runs shadowless")
    if "blend" in d:                          # the per-pixel blend, and a failover as an alarm under the table
        lines += blend_lines(d["blend"])
    for n in d["nodes"]:
        if n.get("left"):
            lines.append(f"{n['slot']}: left on purpose: {n['left']}")
        elif n["state"] == "lost" and n.get("last_seen_age_ms") is not None:
            lines.append(f"{n['slot']}: lost: its node went silent {ago(n['last_seen_age_ms'] / 1e3)}")
        if n["show"]["alone_ms"]:
            lines.append(f"{n['slot']}: went on without the coordinator for {n['show']['alone_ms'] / 1e3:.1f} s "
                         "(its last outage)")
        if n.get("assignment_refused"):
            lines.append(f"{n['slot']}: refused assignment {n['assignment_refused']}; it shows r{n['revision']}")
        for item in n["assets"]["items"]:
            if "error" in item:
                lines.append(f"{n['slot']}: asset {item['id'][:12]} ({item['name']}): {item['error']}")
    s = d["sync"]
    fmt = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    lines.append(f"sync: {s['frames']} frames, skew p50 {fmt(s['skew_p50_ms'])} ms, p99 {fmt(s['skew_p99_ms'])} ms, "
                 f"max {fmt(s['skew_max_ms'])} ms ({s['skew_source'] or 'no data'}); late {s['late']}, dropped {s['dropped']}, "
                 f"out of order {s['out_of_order']}")
    for n in d["nodes"]:                      # why a slot has no node: its newest refused join
        ref = n.get("refusal")
        if ref:
            times = f"{ref['count']}x, last " if ref.get("count", 1) > 1 else ""
            lines.append(f"{n['slot']}: refused from {ref['peer']}: {ref['reason']} ({times}{ref['age_s']:.0f} s ago)")
    for ref in d["refusals"][:5]:            # newest first, counted per address, slot and reason
        times = f"{ref['count']}x, last " if ref.get("count", 1) > 1 else ""
        lines.append(f"refused {ref['peer']} {ref['slot'] or '-'}: {ref['reason']} ({times}{ref['age_s']:.0f} s ago)")
    lines += status_extra_lines(d)
    return "\n".join(lines)


def status_extra_lines(d: dict) -> list[str]:
    """The console's address (loud when it is not served) and the calls refused before authentication."""
    out = []
    console = d.get("console", "")
    if console and console != "off":
        out.append(f"console: {console}")
    b = d.get("before_auth")
    if b and (b["refused"] or b["malformed"] or b["in_flight_calls"]):
        mib = 1024 * 1024
        out.append(f"before authentication: {b['refused']} calls refused over the budget, {b['malformed']} malformed, "
                   f"{b['admitted']} admitted, {b.get('waited', 0)} waited for room; in flight {b['in_flight_calls']} calls, "
                   f"{b['in_flight_bytes'] / mib:.1f} MiB (budget {b['max_calls']} calls, "
                   f"{b['max_bytes'] / mib:.0f} MiB; per address {b['max_calls_per_address']}, "
                   f"{b['max_bytes_per_address'] / mib:.0f} MiB)")
    return out


def _npy(path: Path, dtypes: tuple[str, ...], what: str) -> np.ndarray:
    try:
        return read_npy(path, dtypes, what)
    except RigError as exc:
        raise OperatorError(str(exc)) from None


def read_image(path: str, *, clip: bool = False, hint: str = "clip it to 0..1 first") -> np.ndarray:
    """Read an image file as (H, W, C) RGB (alpha dropped): any format of
    :func:`coordinator.image_decode.decode_image` (8/16-bit integer, float32), or a float32/uint8/
    uint16 .npy. Float pixels must lie in 0..1: ``clip`` clips them, else OperatorError names the
    range found and ``hint``."""
    p = Path(path)
    if not p.is_file():
        raise OperatorError(f"{p}: {'not a file' if p.exists() else 'no such file'}")
    if p.suffix == ".npy":
        img = _npy(p, ("float32", "float64", "uint8", "uint16"), "image")
        img = img.astype(np.float32) if img.dtype == np.float64 else img
    else:
        try:
            img = read_image_file(p)
        except ImageRefused as exc:
            raise OperatorError(str(exc)) from None
        img = drop_alpha(img)
        if img.dtype not in (np.uint8, np.uint16, np.float32):
            img = img.astype(np.float32)
    try:
        return check_float_range(img, str(p), clip=clip, hint=hint)
    except ValueError as exc:
        raise OperatorError(str(exc)) from None


#: what `show` and `play` say of float content outside 0..1
CLIP_HINT = "pass --clip to clip it to 0..1"


def read_lut(path: str | Path) -> np.ndarray:
    """An inverse-response LUT from a .npy: (3, E) (a curve per channel, R G B) or (E,) (one
    curve for every channel, sent as (1, E), which every node applies to each channel); float32
    or float64, 2 <= E <= 65536, finite values in 0..1. Returns (C, E) float32, C in {1, 3}."""
    p = Path(path)
    lut = _npy(p, ("float32", "float64"), "LUT")
    if lut.ndim == 1:
        lut = lut[None, :]
    elif lut.ndim == 2 and lut.shape[0] == 1:
        pass                                    # (1, E): already one curve for every channel
    elif lut.ndim != 2 or lut.shape[0] != 3:
        hint = "; transpose it (lut.T)" if lut.ndim == 2 and lut.shape[1] == 3 and lut.shape[0] != 3 else ""
        raise OperatorError(f"{p}: a LUT must be (3, E) (a curve per channel) or (E,) (one curve for all), "
                            f"got shape {lut.shape}{hint}")
    lut = lut.astype(np.float32)
    try:
        validate_lut(lut)
    except ValueError as exc:
        lo, hi = (float(np.nanmin(lut)), float(np.nanmax(lut))) if lut.size and not np.isnan(lut).all() else (0, 0)
        found = f" (found {lo:.6g} to {hi:.6g})" if "values" in str(exc) else ""
        raise OperatorError(f"{p}: {exc}{found}") from None
    return lut


# ---------------------------------------------------------------- commands
STATUS_HELP = """\
the table's columns:
  state      live (reporting), joined (streams opening), expected (no node yet), lost (its reports
             stopped), left (it stopped on purpose, with why), refused (a node claiming the slot was
             turned away: the reason is under the table)
  offset ms  the node's clock against the rig's, as the node estimates it ("-": no clock exchange yet,
             or the node is lost or left, so its last figures no longer hold; drift and rtt alike)
  drift ppm  how fast its clock runs away from the rig's, in parts per million (settles in about 20 s)
  rtt ms     the round trip of its clock exchanges with the coordinator
  last swap  when its picture last changed (the show's frame while one plays), a clock time and an age
  shown, late, drop   frames it showed, showed late, and never showed
  pose       homography (a table), projection (a 3x4 pose, an object) or none (the projector shows black)
  show       its own account of a timeline show: state and last frame
  assets     content assets ready/wanted and the share of their bytes it holds (! one failed)

examples:
  shadowless status --rig-dir rigs/table
  watch -n 2 shadowless status --rig-dir rigs/table        # keep it on a screen
  shadowless status --rig-dir rigs/table --json            # the same and more, for scripts
"""


def configure_status(p: argparse.ArgumentParser) -> None:
    p.description = ("Show the rig: every slot's node state, clock offset, drift, last swap, late/dropped frames, its "
                     "readiness (assets ready/wanted and the share of their bytes it holds), and the swap skew.")
    p.epilog = STATUS_HELP
    p.add_argument("--json", action="store_true", help="print JSON for scripts instead of a table")
    add_connection_args(p)


SHOW_ACTIONS = ("pause", "resume", "seek", "stop")

#: the files a folder of frames is made of (sorted by name)
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".npy")

SHOW_HELP = """\
examples:
  shadowless show poster.png --rig-dir rigs/table                # until the next show, stop or blackout
  shadowless show poster.png --persist --rig-dir rigs/table      # the rig's content, kept over restarts
  shadowless show photo.jpg --fit cover --rig-dir rigs/table     # another aspect: fill, cropped
  shadowless show pause --rig-dir rigs/table                     # a show started by `shadowless play ASSET`
  shadowless show seek 250 --in 2 --rig-dir rigs/table           # frame 250, two seconds from now
"""

PLAY_HELP = """\
examples:
  shadowless play intro.mp4 --loop --rig-dir rigs/table          # an asset (`shadowless content add`)
  shadowless play frames/ --fps 25 --rig-dir rigs/table          # a folder of images, sent frame by frame
  shadowless play --pattern counter --rig-dir rigs/table         # a counter: the sync figures
  shadowless stop --rig-dir rigs/table                           # the rig's content again
"""


def configure_show(p: argparse.ArgumentParser) -> None:
    p.description = ("Show an image on every projector (warped by each one's pose). 16-bit PNGs and float32 .npy "
                     "files keep their precision. `shadowless show pause|resume|seek FRAME|stop` controls the "
                     "timeline show started by `shadowless play ASSET` (each change takes effect on every node at "
                     "the same instant, the coordinator's lead from now, or --in SECONDS).")
    p.epilog = SHOW_HELP
    p.add_argument("image", help="image file (PNG/TIFF/JPEG, or .npy float32 in [0,1]), or pause, resume, seek, stop")
    p.add_argument("frame", nargs="?", type=cli_types.int_range(0), help="with seek: the asset frame to show")
    p.add_argument("--persist", action="store_true", help="make it the rig's content (shown again after a restart)")
    p.add_argument("--clip", action="store_true",
                   help="clip a float image's values to 0..1 (without it, values outside 0..1 are refused)")
    p.add_argument("--fit", choices=["contain", "cover", "stretch"],
                   help="an image of another aspect than the rig's content area: contain (whole, black bars), cover "
                        "(fills it, cropped) or stretch (distorted); without --fit it is refused")
    p.add_argument("--in", dest="in_s", type=cli_types.number(0, 86400), default=0.0, metavar="SECONDS",
                   help="with pause/resume/seek/stop: take effect this long from now (default: the coordinator's lead)")
    p.add_argument("--json", action="store_true", help="with pause/resume/seek/stop: print the show state as JSON")
    add_connection_args(p)


def configure_play(p: argparse.ArgumentParser) -> None:
    p.description = ("Play an asset of the rig's store on a timeline (each node decodes it from its own cache and "
                     "swaps every frame at its time; the coordinator sends only start, pause, seek, stop), or a "
                     "sequence of images (a folder, sorted by name) or a generated counter pattern, frame by frame.")
    p.epilog = PLAY_HELP
    p.add_argument("source", nargs="?", help="an asset (id, id prefix or name; see `shadowless content list`) or a "
                   "folder of images (omit with --pattern)")
    p.add_argument("--pattern", choices=["counter"], help="generate frames on the coordinator instead")
    p.add_argument("--frames", type=cli_types.int_range(1, 1_000_000), default=150, help="with --pattern: how many frames (default 150)")
    p.add_argument("--fps", type=cli_types.number(0, 1000, lo_open=True), default=None, help="frame rate (default: an asset's own, else 30)")
    p.add_argument("--in", dest="in_s", type=cli_types.number(0, 86400), default=0.0, metavar="SECONDS",
                   help="an asset starts this long from now (default: the coordinator's lead)")
    p.add_argument("--loop", action="store_true", help="an asset plays in a loop until stopped")
    p.add_argument("--start-without", action="store_true",
                   help="start an asset even if some live node does not hold it yet (it joins once it does)")
    p.add_argument("--loops", type=cli_types.int_range(0, 100_000), default=0, help="extra loops (default 0: once)")
    p.add_argument("--fit", choices=["contain", "cover", "stretch"],
                   help="a folder's images of another aspect than the rig's content area: contain (whole, black bars), cover "
                        "(fills it, cropped) or stretch (distorted); without --fit it is refused")
    p.add_argument("--no-wait", action="store_true", help="return at once instead of waiting for the figures")
    p.add_argument("--clip", action="store_true",
                   help="clip a folder's float images to 0..1 (without it, values outside 0..1 are refused)")
    p.add_argument("--allow-partial", action="store_true",
                   help="exit 0 even if not every live node showed every frame of a played sequence (default: "
                        "exit 1 and say what was missed)")
    p.add_argument("--latency-ms", type=cli_types.number(0, 10000), default=0.0, metavar="MS",
                   help="a played sequence's frames are sent this far ahead of their time (default: rig.toml's "
                        "latency_ms)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument("--compensate", action="store_true", help="compensate the rig's blur frame by frame (warm-started "
                   "solves over the measured light transport, see `shadowless compensate`), then play")
    p.add_argument("--iterations", type=cli_types.int_range(1, 1000), default=4, help="with --compensate: solver iterations per frame (default 4)")
    add_connection_args(p)


def configure_configure(p: argparse.ArgumentParser) -> None:
    p.description = "Set a slot's pose, LUT, gain or output size by hand (calibration normally does this)."
    p.add_argument("--slot", required=True)
    pose = p.add_mutually_exclusive_group()
    pose.add_argument("--homography", metavar="FILE_OR_9_NUMBERS",
                      help="a table's pose, content px -> projector px: a .npy (3,3) file or 9 comma-separated "
                           "numbers, row-major")
    pose.add_argument("--projection", metavar="FILE_OR_12_NUMBERS",
                      help="an object's pose, world mm -> projector px: a .npy (3,4) file or 12 comma-separated "
                           "numbers, row-major; with --mesh or --mesh-id")
    p.add_argument("--mesh", type=cli_types.existing_file, metavar="OBJ_OR_PLY",
                   help="with --projection: the object's mesh, with texture coordinates (sent with the pose)")
    p.add_argument("--mesh-id", metavar="ID", help="with --projection: a mesh the rig already holds (RIG/meshes/ID.npz)")
    p.add_argument("--lut", type=cli_types.existing_file, metavar="NPY",
                   help="inverse-response LUT .npy: (3, E) float (a curve per channel) or (E,) (one curve for every "
                        "channel), 2 <= E <= 65536 entries in 0..1")
    p.add_argument("--gain", type=cli_types.number(0, 16), help="linear gain, 0..16 (0 switches the projector's light off)")
    p.add_argument("--resolution", type=cli_types.size, metavar="WxH", help="output size, e.g. 1920x1080")
    p.add_argument("--clear-pose", action="store_true", help="remove the pose (the projector shows black)")
    add_connection_args(p)


def configure_stop(p: argparse.ArgumentParser) -> None:
    p.description = ("Stop what plays (a played sequence or a timeline show): every projector shows the rig's "
                     "content again, or black when it has none.")
    add_connection_args(p)


def configure_blackout(p: argparse.ArgumentParser) -> None:
    p.description = ("Black on every projector at once, until the next show or `shadowless stop` (the rig's content "
                     "is kept, and shown again after a coordinator restart).")
    add_connection_args(p)


async def _stop(args) -> int:
    async with await open_client(args) as c:
        showing = await c.stop(blackout=args.command == "blackout")
    print(f"the rig shows {showing}")
    return 0


async def _status(args) -> int:
    async with await open_client(args) as c:
        d = status_dict(await c.status())
    print(json.dumps(d, indent=2) if args.json else status_table(d, tty=sys.stdout.isatty()))
    return 0


async def _show_control(args) -> int:
    action = args.image
    if action == "seek" and args.frame is None:
        raise OperatorError("seek needs the frame: shadowless show seek FRAME")
    async with await open_client(args) as c:
        if action == "seek":
            st = await c.seek_show(args.frame, delay_s=args.in_s)
        else:
            st = await getattr(c, f"{action}_show")(delay_s=args.in_s)
    print(json.dumps(show_dict(st), indent=2) if args.json else show_line(st))
    return 0


async def warn_unposed(c) -> None:
    """Say on stderr which slots have no pose: content is warped by each slot's pose, so they show black."""
    unposed = [n.slot for n in (await c.status()).nodes if n.pose_kind == "none"]
    if unposed:     # the console shows the same line (coordinator/unposed.py)
        print(f"warning: {unposed_warning(unposed)}", file=sys.stderr)


async def _show(args) -> int:
    if args.image in SHOW_ACTIONS and not Path(args.image).exists():
        return await _show_control(args)
    img = read_image(args.image, clip=args.clip, hint=CLIP_HINT)
    async with await open_client(args) as c:
        r = await c.show(img, name=Path(args.image).name, persist=args.persist, fit=args.fit or "")
        await warn_unposed(c)
    print(f"showing {args.image} ({img.shape[1]}x{img.shape[0]} {img.dtype}), content {r.content_id}")   # the frame id is for machines
    return 0


def play_dict(r: PlayResult) -> dict:
    """A played sequence's figures as JSON."""
    s = sync_dict(r.sync)
    return {"frames_sent": r.frames_sent, "frames_shown": r.frames_shown, "frames_late": r.frames_late,
            "frames_dropped": r.frames_dropped, "nodes": r.nodes, "wall_s": round(r.wall_s, 3),
            "coordinator_cpu_s": round(r.coordinator_cpu_s, 4), "encode_cpu_s": round(r.encode_cpu_s, 4), "sync": s}


async def _play_asset(args) -> int:
    async with await open_client(args) as c:
        st = await c.play_asset(args.source, delay_s=args.in_s, loop=args.loop, fps=args.fps or 0.0,
                                start_without=args.start_without)
        await warn_unposed(c)
    print(json.dumps(show_dict(st), indent=2) if args.json else
          f"{show_line(st)}; starts in {max(0, st.anchor_ns - st.now_ns) / 1e9:.3f} s")
    return 0


async def _play_until_interrupted(c, st: PlaySettings, frames: list[np.ndarray]) -> PlayResult:
    """``c.play``; Ctrl-C stops the sequence on the rig, not only here, and raises KeyboardInterrupt.

    The interrupt is caught by a handler of its own rather than through the task's cancellation: a
    gRPC stream-unary call can swallow a cancellation that lands while it sends (grpc/grpc#43502), and
    the sequence would then play on with the command waiting for it."""
    loop = asyncio.get_running_loop()
    task = asyncio.ensure_future(c.play(st, frames))
    interrupted = asyncio.Event()
    waiter = asyncio.ensure_future(interrupted.wait())
    loop.add_signal_handler(signal.SIGINT, interrupted.set)
    try:
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        loop.remove_signal_handler(signal.SIGINT)
        waiter.cancel()
    if task.done():
        return task.result()
    task.cancel()
    try:
        async with asyncio.timeout(10):
            showing = await c.stop()
        print(f"stopped on the rig; it shows {showing}", file=sys.stderr)
    except (asyncio.TimeoutError, OperatorError) as exc:
        print(f"could not stop the sequence on the rig ({exc}); run `shadowless stop`", file=sys.stderr)
    await asyncio.wait({task}, timeout=5)      # the call ends with the sequence
    if task.done() and not task.cancelled():
        task.exception()                       # retrieved: the call's own end is no news after Ctrl-C
    raise KeyboardInterrupt


async def _play(args) -> int:
    frames: list[np.ndarray] = []
    if args.source and not args.pattern and not args.compensate and not Path(args.source).is_dir():
        if "/" in args.source or Path(args.source).exists():   # a path, not an asset's name
            raise OperatorError(f"{args.source}: {'not a folder' if Path(args.source).exists() else 'no such folder'}"
                                " (play takes a folder of images, or an asset's name or id)")
        return await _play_asset(args)
    args.fps = args.fps or 30.0
    if not (args.latency_ms >= 0 and math.isfinite(args.latency_ms)):
        raise OperatorError(f"--latency-ms must be a positive number of milliseconds, got {args.latency_ms:g}")
    st = PlaySettings(fps=args.fps, loops=args.loops, wait=not args.no_wait, latency_ms=args.latency_ms,
                      fit=args.fit or "")
    if args.compensate:
        return await _play_compensated(args)
    if args.pattern:
        st = PlaySettings(fps=args.fps, loops=args.loops, wait=not args.no_wait, pattern=args.pattern, frames=args.frames,
                          latency_ms=args.latency_ms)
    elif args.source:
        files = sorted(p for p in Path(args.source).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise OperatorError(f"no images in {args.source}")
        frames = [read_image(str(f), clip=args.clip, hint=CLIP_HINT) for f in files]
    else:
        raise OperatorError("give a folder of images or --pattern counter")
    async with await open_client(args) as c:
        await warn_unposed(c)
        r = await _play_until_interrupted(c, st, frames)
    d = play_dict(r)
    p99 = d["sync"]["skew_p99_ms"]      # None: fewer than two nodes swapped a frame, nothing to compare
    skew = f"skew p99 {p99:.3f} ms" if p99 is not None else \
        "no skew (one node)" if d["nodes"] == 1 else "no skew measured"
    print(json.dumps(d, indent=2) if args.json else
          f"played {d['frames_sent']} frames on {count(d['nodes'], 'node')}: shown by all {d['frames_shown']}, late {d['frames_late']}, "
          f"dropped {d['frames_dropped']}; {skew}")
    if args.no_wait or (r.nodes and r.frames_shown >= r.frames_sent):
        return 0
    missed = (f"{r.frames_sent - r.frames_shown} of {r.frames_sent} frames were not shown by every live node "
              f"({r.frames_late} late, {r.frames_dropped} dropped)" if r.nodes else "no live node showed the sequence")
    if args.allow_partial:
        print(f"note: {missed}", file=sys.stderr)
        return 0
    print(f"error: {missed}; pass --allow-partial to accept that", file=sys.stderr)
    return 1


async def _play_compensated(args) -> int:
    """`play --compensate`: the coordinator's compensate_sequence job (progress on stderr)."""
    # only this command needs the compensation package (SciPy, OpenCV); status/show/play stay light
    from coordinator.compensation.image_param import encode_image_param

    if args.pattern or not args.source:
        raise OperatorError("--compensate plays a folder of images (not a generated pattern)")
    files = sorted(p for p in Path(args.source).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise OperatorError(f"no images in {args.source}")
    params = {"frames": [encode_image_param(f) for f in files], "fps": args.fps, "loops": args.loops,
              "iterations": args.iterations}
    async with await open_client(args) as c:
        r = await run_job(c, "compensate_sequence", params)
    print(json.dumps(r, indent=2) if args.json else
          f"compensated {r['frames']} frames ({r['ms_per_frame_mean']} ms per frame after the first, {r['iterations_per_frame']} "
          f"iterations each), played {r['play']['frames_sent']} frames on {count(r['play']['nodes'], 'node')}: late "
          f"{r['play']['frames_late']}, dropped {r['play']['frames_dropped']}")
    return 0


def _matrix(text: str, rows: int, cols: int, what: str) -> np.ndarray:
    """``--homography``/``--projection``: a .npy file of shape (rows, cols) or rows*cols numbers."""
    n = rows * cols
    if Path(text).exists():
        m = _npy(Path(text), ("float32", "float64"), what).astype(np.float64)
    else:
        try:
            m = np.array([float(v) for v in text.split(",")], dtype=np.float64)
        except ValueError:
            raise OperatorError(f"--{what}: not a .npy file nor {n} comma-separated numbers: {text!r}") from None
    if m.size != n:
        raise OperatorError(f"a {what} needs {n} numbers ({rows}x{cols}, row-major), got {m.size}")
    if not np.all(np.isfinite(m)):
        raise OperatorError(f"--{what}: every number must be finite")
    return m.reshape(rows, cols)


def _mesh_arrays(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """--mesh FILE (.obj/.ply with texture coordinates) as (vertices, uvs, faces), refused before
    sending when it would not fit in one request."""
    try:
        m = read_mesh(path)
    except MeshFileError as exc:
        raise OperatorError(str(exc)) from None
    if m.uvs is None:
        raise OperatorError(f"mesh {path} has no texture coordinates: content is mapped through them (UV space)")
    size = m.vertices.shape[0] * 20 + m.faces.shape[0] * 12
    if size > MAX_REQUEST_BYTES - (64 << 10):
        raise OperatorError(f"mesh {path} is {size / 2**20:.1f} MiB as sent ({m.vertices.shape[0]} vertices, "
                            f"{m.faces.shape[0]} faces), more than one request may carry ({MAX_REQUEST_BYTES >> 20} MiB): "
                            "decimate it, or name a mesh the rig already holds with --mesh-id")
    return m.vertices, m.uvs, m.faces


async def _configure(args) -> int:
    h = proj = mesh = None
    if args.homography:
        h = _matrix(args.homography, 3, 3, "homography")
    if args.projection is not None:
        proj = _matrix(args.projection, 3, 4, "projection")
        if bool(args.mesh) == bool(args.mesh_id):
            raise OperatorError("a --projection pose needs its mesh: --mesh FILE (.obj/.ply) or --mesh-id ID "
                                "(a mesh the rig holds)")
        mesh = _mesh_arrays(args.mesh) if args.mesh else None
    elif args.mesh or args.mesh_id:
        raise OperatorError("--mesh and --mesh-id go with --projection")
    lut = read_lut(args.lut) if args.lut else None
    async with await open_client(args) as c:
        revision = await c.configure(args.slot, homography=h, lut=lut, gain=args.gain, size=args.resolution,
                                     clear_pose=args.clear_pose, projection=proj, mesh=mesh,
                                     mesh_id=args.mesh_id or "")
    print(f"slot {args.slot} now at revision {revision}")
    return 0


def _runner(coro_fn):
    def run(args) -> int:
        try:
            return asyncio.run(coro_fn(args))
        except (OperatorError, auth.TokenError) as exc:     # a refused call too (CallRefused)
            said = str(exc)
            if hasattr(args, "fit"):        # the coordinator's words (the console's too) name no option
                said = said.replace("choose how to fit it:", "choose how to fit it with --fit:")
            print(f"shadowless {args.command}: {said}", file=sys.stderr)
            return 2

    return run


run_status = _runner(_status)
run_show = _runner(_show)
run_play = _runner(_play)
run_configure = _runner(_configure)
run_stop = _runner(_stop)
run_blackout = _runner(_stop)
