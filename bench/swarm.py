"""`shadowless bench swarm`: the coordinator's cost per node, measured with a swarm.

For each node count: make a rig with that many slots and two assets (a short sequence of frames
at ``--size`` and one at 64x48, so the timeline's cost can be compared across resolutions), start
a coordinator process and a ``shadowless swarm`` process (mDNS on 127.0.0.1), wait until every
swarm node is live and holds the assets, let the clocks settle, then measure the coordinator's CPU
time (``/proc/PID/stat``, user + system) over windows of:

* ``idle``: joined, nothing playing (pings, heartbeats);
* ``timeline`` at each ``--fps`` and each asset size: ``timeline_cpu_ms_per_node_per_s`` is the
  coordinator's CPU during timeline playback divided by nodes and seconds;
* ``live``: a played sequence of generated frames (``play``, at the rig's content size
  ``--live-size``), ``live_cpu_ms_per_frame`` its CPU divided by the frames sent;

and its resident memory (``VmRSS``, and the peak ``VmHWM``). The swarm's own CPU and whether it
kept up (the fraction of its swaps it reported on time) are read from its stats file for the same
windows: figures measured while the swarm fell behind understate the coordinator's load.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.machine import machine
from bench.workdir import run_dir
from coordinator.api import NodeState, PlaySettings
from coordinator.assets import AssetStore
from rigctl.commands import play_dict
from node.image_files import write_png
from shadowless.local import LocalRig, grid_names
from shadowless.process_stop import stop_process

TICK_S = os.sysconf("SC_CLK_TCK")

#: swarm arguments per --rates preset
RATES = {
    "node": [],
    # what a node did before it settled its clock exchanges and sent a show's reports with its
    # heartbeat: pings at 4 Hz always, every swap batch within 50 ms, a heartbeat every 500 ms
    "dense": ["--ping-settled-s", "0", "--timeline-batch-ms", "50", "--heartbeat-ms", "500"],
}


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", default="16,64,256", help="swarm node counts, comma-separated (default 16,64,256)")
    p.add_argument("--fps", default="30,60", help="timeline frame rates, comma-separated (default 30,60)")
    p.add_argument("--size", default="1920x1080", help="the large asset's frame size WxH (default 1920x1080)")
    p.add_argument("--seconds", type=float, default=10.0, help="length of each measured window (default 10)")
    p.add_argument("--warmup", type=float, default=25.0,
                   help="seconds after joining before measuring: a node's clock settles in ~20 s (default 25)")
    p.add_argument("--live-fps", type=float, default=30.0, help="frame rate of the live sequence (default 30)")
    p.add_argument("--live-size", default="320x180",
                   help="the rig's content size WxH, which the live sequence's generated frames have (default 320x180)")
    p.add_argument("--join-timeout", type=float, default=300.0, help="seconds for every node to join (default 300)")
    p.add_argument("--rates", choices=sorted(RATES), default="node",
                   help="message rates of the swarm nodes: 'node' as a node does (default: pings at 4 Hz until its "
                        "clock is settled, then every 5 s; a show's swap reports with the heartbeat, once a second), "
                        "'dense' as nodes did before (pings at 4 Hz, reports within 50 ms, heartbeats every 500 ms)")
    p.add_argument("--swarm-arg", action="append", default=[], metavar="ARG",
                   help="pass ARG to `shadowless swarm` (repeatable), e.g. --swarm-arg=--ping-settled-s=10")
    p.add_argument("--keep", metavar="DIR", help="keep rig directories and logs here")


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (from /proc; its threads included)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rfind(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / TICK_S


def proc_mem_mb(pid: int) -> dict[str, float]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = round(int(rest.split()[0]) / 1024.0, 1)
    return out


def write_frames(folder: Path, w: int, h: int, n: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    x = np.linspace(0, 255, w, dtype=np.float32)[None, :, None]
    for i in range(n):
        img = np.broadcast_to((x + i * 16) % 256, (h, w, 3)).astype(np.uint8)
        write_png(folder / f"{i:04d}.png", img)


class Window:
    """CPU of the coordinator and the swarm, and the swarm's counters, over one measured window."""

    def __init__(self, coord_pid: int, swarm_pid: int, stats_file: Path):
        self.pids, self.stats_file = (coord_pid, swarm_pid), stats_file

    def _fresh_stats(self, timeout: float = 10.0) -> dict:
        """The swarm's counters as it next writes them (four times a second; a busy machine delays
        it): read at once, a window shorter than the writes' spacing could see one write at both
        ends and count nothing. After ``timeout`` s without a write, what the file holds."""
        since = time.time()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if self.stats_file.stat().st_mtime > since and (doc := read_stats(self.stats_file)):
                    return doc
            except OSError:
                pass
            time.sleep(0.02)
        return read_stats(self.stats_file)

    def __enter__(self) -> Window:
        self.s0 = self._fresh_stats()
        self.t0 = time.monotonic()
        self.cpu0 = [proc_cpu_s(p) for p in self.pids]
        return self

    def __exit__(self, *exc) -> None:
        s1 = self._fresh_stats()
        self.wall = time.monotonic() - self.t0
        cpu1 = [proc_cpu_s(p) for p in self.pids]
        self.coord_cpu, self.swarm_cpu = (b - a for a, b in zip(self.cpu0, cpu1))
        self.swaps = s1.get("swaps", 0) - self.s0.get("swaps", 0)
        self.late = s1.get("woke_late", 0) - self.s0.get("woke_late", 0)
        self.arrived_late = s1.get("arrived_late", 0) - self.s0.get("arrived_late", 0)
        self.live = s1.get("live", 0)
        self.lost = s1.get("sessions_lost", 0) - self.s0.get("sessions_lost", 0)

    def figures(self) -> dict:
        due = self.swaps + self.late
        return {"wall_s": round(self.wall, 2), "coordinator_cpu_s": round(self.coord_cpu, 3),
                "swarm_cpu_s": round(self.swarm_cpu, 3), "swarm_cpu_fraction_of_core": round(self.swarm_cpu / self.wall, 3),
                "swarm_live": self.live, "swarm_swaps": self.swaps, "swarm_woke_late": self.late,
                "swarm_frames_arrived_late": self.arrived_late, "swarm_sessions_lost": self.lost,
                "swarm_on_time_fraction": round(self.swaps / due, 4) if due else None}


def read_stats(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


async def _wait_ready(rig: LocalRig, c, n: int, swarm: subprocess.Popen, timeout: float) -> float:
    t0 = time.monotonic()
    while True:
        st = await c.status()
        ready = sum(1 for s in st.nodes if s.state == NodeState.LIVE and s.assets_wanted and
                    s.assets_ready == s.assets_wanted)
        if ready >= n:
            return time.monotonic() - t0
        if swarm.poll() is not None:
            raise RuntimeError(f"the swarm exited with {swarm.returncode}:\n{rig.log('swarm')[-3000:]}")
        if time.monotonic() - t0 > timeout:
            raise TimeoutError(f"only {ready} of {n} swarm nodes live with the assets after {timeout:.0f} s:\n"
                               f"{rig.log('swarm')[-2000:]}")
        await asyncio.sleep(0.5)


async def _one(n: int, args, workdir: Path) -> dict:
    w, h = (int(v) for v in args.size.split("x"))
    fpss = [float(v) for v in str(args.fps).split(",") if v.strip()]
    slots = grid_names(n)
    lw, lh = (int(v) for v in args.live_size.split("x"))
    rig = LocalRig(slots, workdir, output_size=(lw, lh), content_size=(lw, lh))
    rig.create()
    store = AssetStore(rig.rig_dir)
    sizes = {"large": (w, h), "small": (64, 48)}
    for name, (aw, ah) in sizes.items():
        write_frames(workdir / f"frames-{name}", aw, ah, 8)
        store.add(workdir / f"frames-{name}", name=name, fps=30)
    stats_file = workdir / "swarm-stats.json"
    swarm = None
    try:
        rig.start_coordinator()
        swarm = rig._spawn("swarm", ["swarm", "--nodes", str(n), "--rig-dir", str(rig.rig_dir), "--mdns-interface",
                                     "127.0.0.1", "--rig", rig.rig_name, "--stats-file", str(stats_file),
                                     *RATES[args.rates], *args.swarm_arg])
        coord = rig.coordinator.pid
        async with await rig.client() as c:
            join_s = await _wait_ready(rig, c, n, swarm, args.join_timeout)
            await asyncio.sleep(args.warmup)
            phases = {}
            with Window(coord, swarm.pid, stats_file) as win:
                await asyncio.sleep(args.seconds)
            phases["idle"] = {**win.figures(), "cpu_ms_per_node_per_s": round(1e3 * win.coord_cpu / n / win.wall, 4)}
            for name in sizes:
                for fps in fpss:
                    st = await c.play_asset(name, loop=True, fps=fps, delay_s=0.5)
                    await asyncio.sleep(1.0)    # the show has started; the coordinator expects its ticks
                    with Window(coord, swarm.pid, stats_file) as win:
                        await asyncio.sleep(args.seconds)
                    before = (await c.status()).sync
                    await c.stop_show()
                    await asyncio.sleep(1.0)
                    phases[f"timeline_{name}_{fps:g}fps"] = {
                        **win.figures(), "fps": fps, "size": f"{sizes[name][0]}x{sizes[name][1]}",
                        "revision": st.revision,
                        "timeline_cpu_ms_per_node_per_s": round(1e3 * win.coord_cpu / n / win.wall, 4),
                        "sync_skew_p99_ms": before.skew_p99_ms, "sync_frames_late": before.frames_late}
            frames = max(1, int(args.live_fps * args.seconds))
            with Window(coord, swarm.pid, stats_file) as win:
                reply = await c.play(PlaySettings(fps=args.live_fps, pattern="counter", frames=frames, wait=True))
            d = play_dict(reply)
            phases["live"] = {**win.figures(), "fps": args.live_fps, "size": args.live_size, "frames_sent": d["frames_sent"],
                              "frames_shown": d["frames_shown"], "frames_late": d["frames_late"],
                              "frames_dropped": d["frames_dropped"], "skew_p99_ms": d["sync"]["skew_p99_ms"],
                              "live_cpu_ms_per_frame": round(1e3 * win.coord_cpu / max(1, d["frames_sent"]), 3)}
            mem = proc_mem_mb(coord)
    finally:
        if swarm is not None:
            stop_process(swarm, timeout=30)
        rig.close()
    timeline = [v["timeline_cpu_ms_per_node_per_s"] for k, v in phases.items() if k.startswith("timeline_")]
    return {
        "nodes": n,
        "timeline_cpu_ms_per_node_per_s": max(timeline),
        "live_cpu_ms_per_frame": phases["live"]["live_cpu_ms_per_frame"],
        "idle_cpu_ms_per_node_per_s": phases["idle"]["cpu_ms_per_node_per_s"],
        "rss_mb": mem.get("VmRSS"), "rss_peak_mb": mem.get("VmHWM"),
        "join_s": round(join_s, 2),
        "swarm_on_time_fraction_min": min((v["swarm_on_time_fraction"] for v in phases.values()
                                           if v.get("swarm_on_time_fraction") is not None), default=None),
        "swarm": read_stats(stats_file),
        "phases": phases,
    }


async def _all(args) -> dict:
    counts = [int(v) for v in str(args.nodes).split(",") if v.strip()]
    runs = []
    for n in counts:
        print(f"bench swarm: {n} swarm nodes …", file=sys.stderr, flush=True)
        with run_dir(args.keep, f"swarm-n{n}") as base:
            runs.append(await _one(n, args, base))
    doc = {
        "benchmark": "swarm",
        "machine": machine(),
        "parameters": {"nodes": counts, "fps": args.fps, "size": args.size, "seconds": args.seconds,
                       "warmup_s": args.warmup, "live_fps": args.live_fps, "live_size": args.live_size, "rates": args.rates,
                       "swarm_args": RATES[args.rates] + args.swarm_arg},
        "target": {"timeline_cpu_ms_per_node_per_s": 0.5, "at_nodes": 256},
        "runs": runs,
    }
    if len(runs) >= 2:
        first, last = runs[0], runs[-1]
        doc["per_node_ratio"] = {
            "nodes": [first["nodes"], last["nodes"]],
            # the coordinator's cost per node should not grow with the node count: near 1
            "timeline": round(last["timeline_cpu_ms_per_node_per_s"] / max(1e-9, first["timeline_cpu_ms_per_node_per_s"]), 3),
            "live_per_frame": round(last["live_cpu_ms_per_frame"] / max(1e-9, first["live_cpu_ms_per_frame"]), 3),
        }
    return doc


def run(args: argparse.Namespace) -> int:
    print(json.dumps(asyncio.run(_all(args)), indent=2))
    return 0
