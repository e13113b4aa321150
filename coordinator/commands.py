"""Operator commands: `shadowless status`, `show`, `play`, `configure`.

They talk to a running coordinator through :class:`coordinator.client.Client`, after the
same rig-token handshake the nodes use, and print tables (or JSON for scripts).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
from pathlib import Path

import grpc
import numpy as np

from coordinator.api import NodeStatus, PlayResult, PlaySettings, RigStatus, SyncSummary
from coordinator.client import OperatorError, add_connection_args, open_client
from coordinator.job_command import run_job
from protos import auth


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
                       **({"error": a.error} if a.error else {})} for a in n.assets]}


def assets_cell(a: dict) -> str:
    """The status table's readiness column: ``2/3 41%`` (``-`` when nothing is wanted; ``!`` when
    the node gave up on an asset)."""
    if not a["wanted"]:
        return "-"
    failed = "!" if any("error" in i for i in a["items"]) else ""
    pct = 100 if a["ready"] == a["wanted"] else min(99, int(a["percent"] or 0))   # 100 % only when all are ready
    return f"{a['ready']}/{a['wanted']} {pct}%{failed}"


def status_dict(st: RigStatus) -> dict:
    """The rig's status as JSON (what `shadowless status --json` prints)."""
    num = _num

    return {
        "rig": {"name": st.rig_name, "id": st.rig_id, "instance": st.instance_id, "dir": st.rig_dir,
                "protocol": st.protocol_version, "uptime_s": round(st.uptime_s, 1), "showing": st.showing,
                "latency_budget_ms": st.latency_budget_ms, "coordinator_cpu_s": round(st.cpu_s, 3)},
        "nodes": [{
            "slot": n.slot, "state": n.state.value, "host": n.hostname, "pid": n.pid,
            "clock_offset_ms": round(n.clock_offset_ms, 3), "drift_ppm": round(n.clock_drift_ppm, 2),
            "rtt_ms": round(n.clock_rtt_ms, 3), "clock_error_ms": num(n.clock_error_ms),
            "last_swap_frame": n.last_swap_frame, "last_swap_age_ms": num(n.last_swap_age_ms),
            "shown": n.frames_shown, "late": n.frames_late, "dropped": n.frames_dropped,
            "pose": n.pose_kind, "revision": n.assignment_revision, "joins": n.joins, "assets": assets_dict(n),
        } for n in st.nodes],
        "sync": sync_dict(st.sync),
        "refusals": [{"peer": r.peer, "slot": r.slot, "reason": r.reason, "age_s": round(r.age_s, 1)} for r in st.refusals],
    }


def status_table(d: dict) -> str:
    r = d["rig"]
    lines = [f"rig {r['name']} ({r['id']})  instance {r['instance']}  up {r['uptime_s']:.0f} s  showing: {r['showing']}"]
    hdr = (f"{'slot':<8}{'state':<10}{'host':<16}{'offset ms':>11}{'drift ppm':>10}{'rtt ms':>8}{'last frame':>18}"
           f"{'shown':>8}{'late':>6}{'drop':>6}  {'pose':<11}assets")
    lines.append(hdr)
    for n in d["nodes"]:
        lines.append(f"{n['slot']:<8}{n['state']:<10}{(n['host'] or '-')[:15]:<16}{n['clock_offset_ms']:>11.3f}{n['drift_ppm']:>10.1f}"
                     f"{n['rtt_ms']:>8.3f}{n['last_swap_frame'] or '-':>18}{n['shown']:>8}{n['late']:>6}{n['dropped']:>6}  "
                     f"{n['pose']:<11}{assets_cell(n['assets'])}")
    for n in d["nodes"]:
        for item in n["assets"]["items"]:
            if "error" in item:
                lines.append(f"{n['slot']}: asset {item['id'][:12]} ({item['name']}): {item['error']}")
    s = d["sync"]
    fmt = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    lines.append(f"sync: {s['frames']} frames, skew p50 {fmt(s['skew_p50_ms'])} ms, p99 {fmt(s['skew_p99_ms'])} ms, "
                 f"max {fmt(s['skew_max_ms'])} ms ({s['skew_source'] or 'no data'}); late {s['late']}, dropped {s['dropped']}, "
                 f"out of order {s['out_of_order']}")
    for ref in d["refusals"][-5:]:
        lines.append(f"refused {ref['peer']} {ref['slot']}: {ref['reason']} ({ref['age_s']:.0f} s ago)")
    return "\n".join(lines)


def read_image(path: str) -> np.ndarray:
    """Read an image file as (H, W, C) RGB: 8/16-bit PNG/TIFF/JPEG via OpenCV, or float32 .npy."""
    p = Path(path)
    if p.suffix == ".npy":
        return np.load(p, allow_pickle=False)
    import cv2  # the coordinator's stack; an operator reading image files has it

    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise OperatorError(f"cannot read image {p} (missing, or not an image OpenCV reads)")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    return img


# ---------------------------------------------------------------- commands
def configure_status(p: argparse.ArgumentParser) -> None:
    p.description = ("Show the rig: every slot's node state, clock offset, drift, last swap, late/dropped frames, its "
                     "readiness (assets ready/wanted and the share of their bytes it holds), and the swap skew.")
    p.add_argument("--json", action="store_true", help="print JSON for scripts instead of a table")
    add_connection_args(p)


def configure_show(p: argparse.ArgumentParser) -> None:
    p.description = ("Show an image on every projector (warped by each one's pose). 16-bit PNGs and float32 .npy "
                     "files keep their precision.")
    p.add_argument("image", help="image file (PNG/TIFF/JPEG, or .npy float32 in [0,1])")
    p.add_argument("--persist", action="store_true", help="make it the rig's content (shown again after a restart)")
    add_connection_args(p)


def configure_play(p: argparse.ArgumentParser) -> None:
    p.description = "Play a sequence of images (a folder, sorted by name) or a generated counter pattern, with synchronized swaps."
    p.add_argument("source", nargs="?", help="a folder of images (omit with --pattern)")
    p.add_argument("--pattern", choices=["counter"], help="generate frames on the coordinator instead")
    p.add_argument("--frames", type=int, default=150, help="with --pattern: how many frames (default 150)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    p.add_argument("--loops", type=int, default=0, help="extra loops (default 0: once)")
    p.add_argument("--no-wait", action="store_true", help="return at once instead of waiting for the figures")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument("--compensate", action="store_true", help="compensate the rig's blur frame by frame (warm-started "
                   "solves over the measured light transport, see `shadowless compensate`), then play")
    p.add_argument("--iterations", type=int, default=4, help="with --compensate: solver iterations per frame (default 4)")
    add_connection_args(p)


def configure_configure(p: argparse.ArgumentParser) -> None:
    p.description = "Set a slot's pose, LUT, gain or output size by hand (calibration normally does this)."
    p.add_argument("--slot", required=True)
    p.add_argument("--homography", metavar="FILE_OR_9_NUMBERS",
                   help="content px -> projector px: a .npy (3,3) file or 9 comma-separated numbers, row-major")
    p.add_argument("--lut", metavar="NPY", help="(C, E) float32 inverse-response LUT")
    p.add_argument("--gain", type=float, help="linear gain (0..16)")
    p.add_argument("--resolution", metavar="WxH", help="output size")
    p.add_argument("--clear-pose", action="store_true", help="remove the pose (the projector shows black)")
    add_connection_args(p)


async def _status(args) -> int:
    async with await open_client(args) as c:
        d = status_dict(await c.status())
    print(json.dumps(d, indent=2) if args.json else status_table(d))
    return 0


async def _show(args) -> int:
    img = read_image(args.image)
    async with await open_client(args) as c:
        r = await c.show(img, name=Path(args.image).name, persist=args.persist)
    print(f"showing {args.image} ({img.shape[1]}x{img.shape[0]} {img.dtype}) as frame {r.frame_id}, content {r.content_id}")
    return 0


def play_dict(r: PlayResult) -> dict:
    """A played sequence's figures as JSON."""
    s = sync_dict(r.sync)
    return {"frames_sent": r.frames_sent, "frames_shown": r.frames_shown, "frames_late": r.frames_late,
            "frames_dropped": r.frames_dropped, "nodes": r.nodes, "wall_s": round(r.wall_s, 3),
            "coordinator_cpu_s": round(r.coordinator_cpu_s, 4), "encode_cpu_s": round(r.encode_cpu_s, 4), "sync": s}


async def _play(args) -> int:
    frames: list[np.ndarray] = []
    st = PlaySettings(fps=args.fps, loops=args.loops, wait=not args.no_wait)
    if args.compensate:
        return await _play_compensated(args)
    if args.pattern:
        st = PlaySettings(fps=args.fps, loops=args.loops, wait=not args.no_wait, pattern=args.pattern, frames=args.frames)
    elif args.source:
        files = sorted(p for p in Path(args.source).iterdir() if p.suffix.lower() in (".png", ".tif", ".tiff", ".jpg", ".npy"))
        if not files:
            raise OperatorError(f"no images in {args.source}")
        frames = [read_image(str(f)) for f in files]
    else:
        raise OperatorError("give a folder of images or --pattern counter")
    async with await open_client(args) as c:
        r = await c.play(st, frames)
    d = play_dict(r)
    print(json.dumps(d, indent=2) if args.json else
          f"played {d['frames_sent']} frames on {d['nodes']} nodes: shown by all {d['frames_shown']}, late {d['frames_late']}, "
          f"dropped {d['frames_dropped']}; skew p99 {d['sync']['skew_p99_ms']} ms")
    return 0


async def _play_compensated(args) -> int:
    """`play --compensate`: the coordinator's compensate_sequence job (progress on stderr)."""
    # only this command needs the compensation package (SciPy, OpenCV); status/show/play stay light
    from coordinator.compensation.image_param import encode_image_param

    if args.pattern or not args.source:
        raise OperatorError("--compensate plays a folder of images (not a generated pattern)")
    files = sorted(p for p in Path(args.source).iterdir() if p.suffix.lower() in (".png", ".tif", ".tiff", ".jpg", ".npy"))
    if not files:
        raise OperatorError(f"no images in {args.source}")
    params = {"frames": [encode_image_param(f) for f in files], "fps": args.fps, "loops": args.loops,
              "iterations": args.iterations}
    async with await open_client(args) as c:
        r = await run_job(c, "compensate_sequence", params)
    print(json.dumps(r, indent=2) if args.json else
          f"compensated {r['frames']} frames ({r['ms_per_frame_mean']} ms per frame after the first, {r['iterations_per_frame']} "
          f"iterations each), played {r['play']['frames_sent']} frames on {r['play']['nodes']} nodes: late "
          f"{r['play']['frames_late']}, dropped {r['play']['frames_dropped']}")
    return 0


async def _configure(args) -> int:
    h = lut = size = None
    if args.homography:
        try:
            if Path(args.homography).exists():
                h = np.load(args.homography).astype(np.float64)
            else:
                h = np.array([float(v) for v in args.homography.split(",")], dtype=np.float64)
        except ValueError:
            raise OperatorError(f"--homography: not a .npy file nor 9 comma-separated numbers: {args.homography!r}") from None
        if h.size != 9:
            raise OperatorError("a homography needs 9 numbers")
    if args.lut:
        lut = np.load(args.lut).astype(np.float32)
    if args.resolution:
        try:
            size = tuple(int(v) for v in args.resolution.lower().split("x"))
        except ValueError:
            raise OperatorError(f"--resolution must be WxH, e.g. 1920x1080, got {args.resolution!r}") from None
    async with await open_client(args) as c:
        revision = await c.configure(args.slot, homography=h, lut=lut, gain=args.gain, size=size,
                                     clear_pose=args.clear_pose)
    print(f"slot {args.slot} now at revision {revision}")
    return 0


def _runner(coro_fn):
    def run(args) -> int:
        try:
            return asyncio.run(coro_fn(args))
        except (OperatorError, auth.TokenError) as exc:
            print(f"shadowless {args.command}: {exc}", file=sys.stderr)
            return 2
        except grpc.aio.AioRpcError as exc:
            print(f"shadowless {args.command}: {exc.details() or exc.code().name}", file=sys.stderr)
            return 2

    return run


run_status = _runner(_status)
run_show = _runner(_show)
run_play = _runner(_play)
run_configure = _runner(_configure)
