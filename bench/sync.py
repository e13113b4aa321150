"""`shadowless bench sync`: swap synchronisation of N real node processes on loopback.

For each node count: start a coordinator and N offscreen nodes (mDNS on
127.0.0.1) whose clocks are made wrong on purpose (offsets spread over
±offset-ms, drifts over ±drift-ppm), let the clock estimators settle, play a
generated sequence at the given frame rate, and report what the coordinator
measured: frames shown/late/dropped, swap skew (max - min swap instant over the
nodes, read from the shared host clock, i.e. the truth), the nodes' clock
estimate error against that truth, and the coordinator's CPU time per frame.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path

from bench.machine import machine
from bench.workdir import run_dir
from coordinator.api import PlaySettings
from rigctl.commands import play_dict
from protos import cli_types
from shadowless.local import LocalRig, grid_names, spread


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=cli_types.int_list(1, 256), default="16", help="node counts, comma-separated (default 16; e.g. 8,16,32)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    p.add_argument("--seconds", type=float, default=10.0, help="sequence length per run (default 10)")
    p.add_argument("--size", type=cli_types.size, default="160x90", help="projector output and content size WxH (default 160x90)")
    p.add_argument("--offset-ms", type=float, default=500.0, help="inject clock offsets within ±this (default 500)")
    p.add_argument("--drift-ppm", type=float, default=200.0, help="inject clock drifts within ±this (default 200)")
    p.add_argument("--warmup", type=float, default=8.0, help="seconds for the clock estimators to settle (default 8)")
    p.add_argument("--latency-ms", type=float, default=50.0, help="scheduling budget (default 50)")
    p.add_argument("--no-realtime", action="store_true", help="nodes swap at normal priority (for comparison)")
    p.add_argument("--keep", metavar="DIR", help="keep rig directories and logs here")


async def _one(n: int, args, workdir: Path) -> dict:
    w, h = args.size
    slots = grid_names(n)
    offsets = dict(zip(slots, spread(n, args.offset_ms, 1)))
    drifts = dict(zip(slots, spread(n, args.drift_ppm, 2)))
    t0 = time.monotonic()
    with LocalRig(slots, workdir, output_size=(w, h), content_size=(w, h), clock_offsets_ms=offsets,
                  clock_drifts_ppm=drifts, latency_ms=args.latency_ms,
                  extra_node_args={s: ["--no-realtime"] for s in slots} if args.no_realtime else None) as rig:
        async with await rig.client() as c:
            await rig.wait_live(c, timeout=300)
            startup = time.monotonic() - t0
            await asyncio.sleep(args.warmup)
            frames = max(1, int(args.fps * args.seconds))
            reply = await c.play(PlaySettings(fps=args.fps, pattern="counter", frames=frames, wait=True))
    d = play_dict(reply)
    s = d["sync"]
    return {
        "nodes": n,
        "fps": args.fps,
        "frames_sent": d["frames_sent"],
        "frames_shown": d["frames_shown"],
        "frames_late": d["frames_late"],
        "frames_dropped": d["frames_dropped"],
        "skew_p50_ms": s["skew_p50_ms"],
        "skew_p99_ms": s["skew_p99_ms"],
        "skew_max_ms": s["skew_max_ms"],
        "skew_source": s["skew_source"],
        "clock_error_p99_ms": s["clock_error_p99_ms"],
        "out_of_order": s["out_of_order"],
        "coordinator_cpu_s": d["coordinator_cpu_s"],
        "coordinator_cpu_ms_per_frame": round(1e3 * d["coordinator_cpu_s"] / max(1, d["frames_sent"]), 4),
        "encode_cpu_ms_per_frame": round(1e3 * d["encode_cpu_s"] / max(1, d["frames_sent"]), 4),
        "startup_s": round(startup, 2),
    }


async def _all(args) -> dict:
    counts = list(args.nodes)
    runs = []
    for n in counts:
        print(f"bench sync: {n} nodes at {args.fps:g} fps for {args.seconds:g} s …", file=sys.stderr, flush=True)
        with run_dir(args.keep, f"sync-n{n}") as base:
            runs.append(await _one(n, args, base))
    doc = {
        "benchmark": "sync",
        "machine": machine(),
        "parameters": {"nodes": counts, "fps": args.fps, "seconds": args.seconds, "size": args.size,
                       "offset_ms": args.offset_ms, "drift_ppm": args.drift_ppm, "warmup_s": args.warmup,
                       "latency_ms": args.latency_ms, "realtime": not args.no_realtime},
        "runs": runs,
    }
    if len(runs) >= 2:
        first, last = runs[0], runs[-1]
        doc["cpu_per_frame_ratio"] = {
            "nodes": [first["nodes"], last["nodes"]],
            "ratio": round(last["coordinator_cpu_ms_per_frame"] / max(1e-9, first["coordinator_cpu_ms_per_frame"]), 3),
            "per_added_node_ms": round((last["coordinator_cpu_ms_per_frame"] - first["coordinator_cpu_ms_per_frame"])
                                       / max(1, last["nodes"] - first["nodes"]), 4),
            # encoding happens once per frame whatever the node count: this ratio should stay near 1
            "encode_ratio": round(last["encode_cpu_ms_per_frame"] / max(1e-9, first["encode_cpu_ms_per_frame"]), 3),
        }
    return doc


def run(args: argparse.Namespace) -> int:
    print(json.dumps(asyncio.run(_all(args)), indent=2))
    return 0
