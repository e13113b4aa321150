"""`shadowless bench venue`: a rig on a virtual venue network (network namespaces, see
:mod:`shadowless.netns`): discovery and asset distribution.

One namespace per process (the coordinator and N nodes with offscreen outputs), joined by a
bridge over ``tc tbf`` rate-limited links (``--link``; the coordinator's ``--coordinator-link``).
A test video (a moving gradient plus noise, so that it does not compress to nothing, at a
realistic bit rate) is generated with PyAV and added to the rig's asset store before any node
starts, and every slot gets the identity homography as its pose (as a calibrated rig has one:
nodes warp the frames they show); then the node processes start, discover the coordinator by multicast mDNS over the
bridge, join, and fetch the asset from the coordinator (``FetchBlob``).

The benchmark polls the coordinator's status (every ``--poll-s``, and every 0.05 s until the
first node is live; through the venue's Unix socket relay, whose connection stays inside the
coordinator's namespace, so polling never crosses a rate-limited link). Instants are read on this
host's monotonic clock as the reply's arrival minus the ages the status reports (how long ago the
coordinator saw each node go live and each asset turn ready; nodes report readiness at once), so
they do not depend on the poll interval:

* ``discovery_s``: from starting the node processes until every node is live (``live_s``: each);
* ``distribution_s``: from the first node live until every node reports the asset ready (each
  node's ``ready_s``, from the same origin);
* ``distribution_ideal_s``: every node's copy through the coordinator's link at its full rate,
  N × asset_bytes × 8 / coordinator link rate (or one copy through a node's link, if that is
  slower), and ``distribution_ratio`` = distribution_s / ideal;
* ``coordinator_cpu_s``, ``node_cpu_s``: CPU time the coordinator used over the distribution,
  and each node from when it was seen live to when it was seen ready;
* ``throughput_mbit_s``: N × asset_bytes × 8 / distribution_s, the aggregate payload rate.

Then the asset is played by timeline (``timeline``: swap skew, late frames, the coordinator's
traffic against streaming raw frames) and one node is killed and restarted mid-show (``rejoin``:
how long until it is back in step, how well it agrees with its peers); see :mod:`bench.venue_show`.
Last, ``live``: a natural-looking sequence at the video's size played as live frames (encoded once
as H.264 by the coordinator, streamed to every node): bytes per node-frame against raw, PSNR,
encode cost; see :mod:`bench.venue_live`.
``decode_ms_per_frame`` is a reference: one software decode of the video on this host.
``--only PART[,PART]`` runs only some of these parts after the distribution (``timeline``,
``rejoin``, ``restart``: the coordinator killed and restarted mid-show, ``live``); the document
has the sections of those that ran. ``--quick`` shortens the shows around the kills (a smoke run
of the benchmark itself, as the test suite makes).

**CPU budgets** (``--node-cpu F``, root and a cgroup cpu controller: :mod:`shadowless.rig_budget`):
every node process is held to F of a core, as if each ran on a small computer of its own, its
rasterizer's threads (llvmpipe, the GPU's stand-in) in a group of their own (``--node-gpu``: no
limit by default), the coordinator in its own (``--coordinator-cpu``: by default what is left of
the machine's cores after the nodes, at least 0.5) and this process in one without a limit.
Restarted processes go back into their groups. The nodes come first: their groups weigh ten
times the coordinator's, so that the coordinator (a restarted one's start-up included) gets what
they leave, as on separate computers; and each node may spend up to ``--cpu-burst`` of its quota
more in one CFS period out of what it saved, so that a frame's work that comes at once is not cut
into 10 ms periods (its average stays F). The document then says ``node_cpu_limit``,
``node_gpu_limit``, ``coordinator_cpu_limit`` and, under ``cpu_budget``, each group's CPU time and
time held back over the whole run (``groups``) and over the timeline show
(``timeline.cpu_budget``). Every group is removed at the end, also on Ctrl-C and on errors, and a
killed run's groups at the next start.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

from bench import venue_live, venue_show
from bench.machine import load, machine
from coordinator.api import NodeState
from coordinator.assets import AssetStore
from coordinator.rig import parse_config
from protos import cli_types
from shadowless.local import LocalRig, grid_names
from shadowless import exit_cleanup
from shadowless.cpu_budget import CpuBudgetError, cleanup_leftovers, unavailable
from shadowless.netns import VenueError, available, parse_rate
from shadowless.rig_budget import DEFAULT_BURST, DEFAULT_PERIOD_MS, RigBudgets, coordinator_default, parse_gpu

#: bit rate of the generated video at 1920x1080, 30 fps (scaled with pixels per second)
REFERENCE_BIT_RATE = 8_000_000
#: encoders tried in this order (the first one the installed PyAV can encode with)
ENCODERS = ("libx264", "h264", "libopenh264", "mpeg4")
#: status poll interval until the first node is live
FIRST_LIVE_POLL_S = 0.05


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"not a size WxH: {text!r}")
    return int(m.group(1)), int(m.group(2))


def _fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a fraction of a core: {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"a share of a core must be > 0, got {text!r}")
    return v


def _gpu(text: str):
    try:
        return parse_gpu(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _rate(text: str) -> str:
    try:
        parse_rate(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


#: what follows the distribution, in order: the timeline show, a node's rejoin, the coordinator's
#: restart (bench/venue_show.py), live frames (bench/venue_live.py)
PARTS = ("timeline", "rejoin", "restart", "live")


def _parts(text: str) -> tuple[str, ...]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in PARTS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"unknown part {', '.join(bad) or repr(text)}; the parts are "
                                         f"{', '.join(PARTS)}")
    return tuple(names)


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("A rig on a virtual venue network (one network namespace per process, a bridge, tc-rate-limited "
                     "links; needs root and iproute2): time to discover the coordinator by multicast mDNS, and time "
                     "to distribute a generated test video to every node, against the link's ideal; then the video "
                     "played by timeline (swap skew, late frames, the coordinator's traffic) and one node killed and "
                     "restarted mid-show (time until it is back in step, frame agreement).")
    p.epilog = ("examples (root; iproute2):\n"
                "  shadowless bench venue --nodes 4 --link 1gbit --seconds 8\n"
                "  shadowless bench venue --nodes 4 --link 100mbit --seconds 8\n"
                "  shadowless bench venue --nodes 8 --link 100mbit --coordinator-link 1gbit\n"
                "  shadowless bench venue --nodes 4 --node-cpu 0.4                # each node a small computer's CPU\n"
                "  shadowless bench venue --nodes 8 --node-cpu 0.2 --size 960x540\n"
                "  shadowless bench venue --nodes 4 --node-cpu 0.4 --output-size 320x180 --only restart\n"
                "  python -m shadowless.cpu_budget cleanup                        # groups a killed run left")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--nodes", type=int, default=4, help="node processes (default 4)")
    p.add_argument("--link", type=_rate, default="1gbit", metavar="RATE",
                   help="every link's rate, tc notation (default 1gbit; e.g. 100mbit)")
    p.add_argument("--coordinator-link", type=_rate, metavar="RATE", help="the coordinator's link rate (default --link)")
    p.add_argument("--size", type=_size, default=(1920, 1080), metavar="WxH", help="test video size (default 1920x1080)")
    p.add_argument("--output-size", type=_size, default=(640, 360), metavar="WxH",
                   help="every node's offscreen output (default 640x360)")
    p.add_argument("--fps", type=float, default=30.0, help="test video frame rate (default 30)")
    p.add_argument("--seconds", type=float, default=5.0, help="test video length (default 5 s)")
    p.add_argument("--live-seconds", type=float, default=2.0,
                   help="length of the live sequence played at --size and --fps (default 2 s; 0: skip it)")
    p.add_argument("--bit-rate", type=float, metavar="BITS_PER_S",
                   help=f"test video bit rate (default {REFERENCE_BIT_RATE / 1e6:g} Mbit/s at 1080p30, "
                        "scaled with pixels per second)")
    p.add_argument("--heartbeat-ms", type=int, default=100,
                   help="the rig's heartbeat (readiness travels in heartbeats: the times' resolution; default 100)")
    p.add_argument("--poll-s", type=float, default=0.2, help="status poll interval (default 0.2 s)")
    p.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds (default 600)")
    p.add_argument("--only", type=_parts, metavar="PART[,PART]",
                   help=f"after the distribution, run only these parts ({', '.join(PARTS)}; default all), e.g. "
                        "--only restart for the coordinator's restart alone")
    p.add_argument("--quick", action="store_true",
                   help="shorter shows around the kills (1.5 s before each, a 2.5 s coordinator outage, 1.5 s after "
                        "each rejoin, instead of 3, 5 and 4 s): a smoke run of the benchmark, its figures say less")
    p.add_argument("--keep", metavar="DIR", help="keep the rig's work directory (rig, logs, caches, video) in DIR")
    b = p.add_argument_group("CPU budgets (root and a cgroup cpu controller, v1 or v2)")
    b.add_argument("--node-cpu", type=_fraction, metavar="F",
                   help="hold every node process to F of a core (one cgroup each), as if each ran on a small "
                        "computer of its own; the coordinator and this benchmark then get groups of their own too, "
                        "and every group is measured (default: no budgets)")
    b.add_argument("--node-gpu", type=_gpu, default=None, metavar="G",
                   help="with --node-cpu: each node's rasterizer threads (llvmpipe, the GPU's stand-in) go in a "
                        "group of their own held to G of a core; 'max' (the default): no limit; 'node': they stay "
                        "in the node's budget, as on a board that draws on its CPU")
    b.add_argument("--coordinator-cpu", type=_fraction, metavar="C",
                   help="with --node-cpu: the coordinator's share of a core (default: what is left of this "
                        "machine's cores after the nodes' budgets, at least 0.5)")
    b.add_argument("--reserve", action="store_true",
                   help="with --node-cpu: give every node's, rasterizer's and the coordinator's group a high CFS "
                        "weight, so that other work on this host does not starve them (each still never gets "
                        "more than its limit; on a quiet host this changes nothing)")
    b.add_argument("--cpu-burst", type=cli_types.number(0, 1), default=DEFAULT_BURST, metavar="B",
                   help=f"with --node-cpu: each node may spend up to B of its quota more in one CFS period out of "
                        f"what it left unused before (0..1, default {DEFAULT_BURST:g}; 0: none), so that a frame's "
                        "work that comes at once is not cut into periods as no computer of its own would cut it; "
                        "its average stays --node-cpu")
    b.add_argument("--cpu-period-ms", type=float, default=DEFAULT_PERIOD_MS, metavar="MS",
                   help=f"the budgets' CFS period (default {DEFAULT_PERIOD_MS:g} ms: a held node waits a few ms at "
                        "a time, as a slower CPU would, not 100 ms)")


# ---------------------------------------------------------------- the test video
def pick_encoder() -> str:
    """The first of :data:`ENCODERS` the installed PyAV can encode with."""
    import av

    def can_encode(name: str) -> bool:
        try:
            av.codec.Codec(name, "w")
        except Exception:   # noqa: BLE001 - a decoder only, or an encoder PyAV cannot open
            return False
        return True

    for name in ENCODERS:
        if name in av.codecs_available and can_encode(name):
            return name
    raise RuntimeError(f"the installed PyAV has none of the encoders {', '.join(ENCODERS)}")


def default_bit_rate(size: tuple[int, int], fps: float) -> int:
    w, h = size
    return max(100_000, int(REFERENCE_BIT_RATE * (w * h * fps) / (1920 * 1080 * 30)))


def make_video(path: Path, *, size: tuple[int, int], fps: float, seconds: float, bit_rate: int,
               seed: int = 0) -> dict:
    """Encode a test video: a gradient that moves, a moving bar pattern and fresh noise in every
    frame (so the encoder spends its bit rate), ``seconds`` long. Returns what was written."""
    import av

    w, h = size
    if w % 2 or h % 2:
        raise ValueError(f"the video size must be even (4:2:0 chroma), got {w}x{h}")
    codec = pick_encoder()
    frames = max(1, round(seconds * fps))
    rng = np.random.default_rng(seed)
    ramp_x = (np.arange(2 * w) % w * 200 // max(1, w - 1)).astype(np.uint8)          # 0..200, moves right
    ramp_y = (np.arange(2 * h) % h * 200 // max(1, h - 1)).astype(np.uint8)          # moves down
    period = 2 * max(8, w // 24)
    bars_idx = (np.arange(h)[:, None] + np.arange(w + period)[None, :]) // (period // 2) % 2
    bars = (bars_idx * 160 + 20).astype(np.uint8)                                    # diagonal bars, move left
    # fresh-looking noise in every frame: a window at a random row of a taller noise field
    noise = rng.integers(0, 48, size=(2 * h, w, 3), dtype=np.uint8)                  # + <= 200: no wrap
    rate = Fraction(fps).limit_denominator(1001)
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=rate)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.bit_rate = int(bit_rate)
        # a keyframe every second, as show content is encoded: a node joining mid-show decodes from
        # the keyframe before its first frame (x264's default, 250 frames, makes that up to 8 s of video)
        s.codec_context.gop_size = max(1, round(fps))
        if codec == "libx264":
            s.options = {"preset": "ultrafast"}     # the content is what it is; encode it quickly
        img = np.empty((h, w, 3), np.uint8)
        for i in range(frames):
            dx, dy, db, dn = (i * 7) % w, (i * 3) % h, (i * 5) % period, int(rng.integers(0, h))
            img[..., 0] = ramp_x[dx:dx + w][None, :]
            img[..., 1] = ramp_y[dy:dy + h][:, None]
            img[..., 2] = bars[:, db:db + w]
            img += noise[dn:dn + h]
            for pkt in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    nbytes = path.stat().st_size
    return {"codec": codec, "frames": frames, "bytes": nbytes,
            "bit_rate_mbit_s": round(nbytes * 8 / (frames / fps) / 1e6, 3)}


# ---------------------------------------------------------------- the run
def calibrate_identity(rig_dir: Path, slots: list[str]) -> None:
    """Give every slot the identity homography (content px = projector px), as calibration would
    a pose: nodes then warp the show's frames as a calibrated rig's do (without a pose, content
    renders black) and decode a larger video straight to the content size."""
    import numpy as np

    from coordinator.rig import HomographyPose, Rig

    rig = Rig(rig_dir)
    for s in slots:
        rig.update_slot(s, pose=HomographyPose(np.eye(3)))


def set_heartbeat(rig_dir: Path, heartbeat_ms: int) -> None:
    """Write ``heartbeat_ms`` (and a matching ``lost_after_ms``) into the rig's rig.toml."""
    path = rig_dir / "rig.toml"
    text = path.read_text()
    lost = max(2500, 5 * heartbeat_ms)
    text, n1 = re.subn(r"(?m)^heartbeat_ms\s*=.*$", f"heartbeat_ms = {heartbeat_ms}", text, count=1)
    text, n2 = re.subn(r"(?m)^lost_after_ms\s*=.*$", f"lost_after_ms = {lost}", text, count=1)
    if not (n1 and n2):
        raise RuntimeError(f"{path}: no heartbeat_ms / lost_after_ms line to set")
    parse_config(text, source=str(path))       # what we write must read back
    path.write_text(text)


def _tail(rig: LocalRig, slots, n: int = 3) -> str:
    return "\n".join(f"--- node {s}:\n{rig.log('node-' + s)[-1500:]}" for s in list(slots)[:n])


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system, every thread) of a live process, from /proc; NaN once it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return math.nan
    fields = stat[stat.rfind(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class _Watch:
    """What the polls saw: each node's live and ready times (s after the nodes started, on this
    host's monotonic clock, read when the status reply arrived) and the CPU time the processes
    used while the asset was being distributed."""

    def __init__(self, rig: LocalRig, asset_id: str, t_start: float):
        self.rig, self.asset_id, self.t_start = rig, asset_id, t_start
        self.live: dict[str, float] = {}
        self.ready: dict[str, float] = {}
        self.cpu_live: dict[str, float] = {}       # a node's CPU time when it was first seen live
        self.cpu_ready: dict[str, float] = {}      # ... and when it was first seen ready
        self.coordinator_cpu: list[float] = []     # at the first node live, at the last node ready

    def see(self, nodes) -> None:
        """Record what a status reply shows. The instants are the reply's arrival minus the ages the
        coordinator reports (``live_age_ms``, ``ready_age_ms``, on its clock), so they do not depend
        on the poll interval; the CPU readings are taken at the poll."""
        now = time.monotonic() - self.t_start
        pids = {s: p.pid for s, p in self.rig.nodes.items()}

        def at(age_ms: float) -> float:
            return now - age_ms / 1e3 if math.isfinite(age_ms) else now

        for n in nodes:
            if n.slot not in pids:
                continue
            if n.state == NodeState.LIVE and n.slot not in self.live:
                self.live[n.slot] = at(n.live_age_ms)
                self.cpu_live[n.slot] = cpu_seconds(pids[n.slot])
            ready = [a for a in n.assets if a.asset_id == self.asset_id and a.ready]
            if n.slot not in self.ready and ready:
                if n.slot not in self.live:
                    self.live[n.slot] = at(n.live_age_ms)
                    self.cpu_live[n.slot] = cpu_seconds(pids[n.slot])
                self.ready[n.slot] = at(ready[0].ready_age_ms)
                self.cpu_ready[n.slot] = cpu_seconds(pids[n.slot])
        coordinator = self.rig.coordinator.pid if self.rig.coordinator is not None else 0
        if self.live and not self.coordinator_cpu:
            self.coordinator_cpu.append(cpu_seconds(coordinator))
        if self.done and len(self.coordinator_cpu) == 1:
            self.coordinator_cpu.append(cpu_seconds(coordinator))

    @property
    def done(self) -> bool:
        return set(self.ready) == set(self.rig.slots)


async def _poll(rig: LocalRig, asset_id: str, args, t_start: float) -> _Watch:
    """Poll the coordinator's status every ``args.poll_s`` (every :data:`FIRST_LIVE_POLL_S` until
    the first node is live) until every node reports the asset ready."""
    watch = _Watch(rig, asset_id, t_start)
    deadline = t_start + args.timeout
    async with await rig.client(timeout=60.0) as c:
        while True:
            t_ask = time.monotonic()
            watch.see((await c.status()).nodes)
            if watch.done:
                return watch
            for s, p in rig.nodes.items():
                if p.poll() is not None:
                    raise RuntimeError(f"node {s} exited with {p.returncode}:\n{rig.log('node-' + s)[-3000:]}")
            if rig.coordinator is not None and rig.coordinator.poll() is not None:
                raise RuntimeError("the coordinator exited:\n" + rig.log("coordinator")[-3000:])
            if time.monotonic() > deadline:
                waiting = sorted(set(rig.slots) - set(watch.ready))
                raise TimeoutError(f"after {args.timeout:.0f} s: live {sorted(watch.live)}, asset ready on "
                                   f"{sorted(watch.ready)}, waiting for {waiting}\n{_tail(rig, waiting)}")
            # until the first node is live (the origin of the distribution's times) nothing is fetched:
            # poll faster then, so that origin is read within FIRST_LIVE_POLL_S
            interval = args.poll_s if watch.live else min(args.poll_s, FIRST_LIVE_POLL_S)
            await asyncio.sleep(max(0.0, interval - (time.monotonic() - t_ask)))


async def _measure(args, workdir: Path, video: Path, budgets: RigBudgets | None) -> dict:
    n = args.nodes
    parts = args.only or PARTS
    slots = grid_names(n)
    ow, oh = args.output_size
    rig = LocalRig(slots, workdir, output_size=(ow, oh), content_size=(ow, oh), netns=True, link=args.link,
                   coordinator_link=args.coordinator_link, env=venue_show.ENV, budgets=budgets)
    try:
        rig.create()                       # the venue, the relay to the coordinator, the rig directory
        print(rig.venue.describe(), file=sys.stderr, flush=True)
        set_heartbeat(rig.rig_dir, args.heartbeat_ms)
        calibrate_identity(rig.rig_dir, slots)
        manifest = AssetStore(rig.rig_dir).add(video)
        rig.start_coordinator()
        async with await rig.client(timeout=60.0) as c:
            await c.status()               # the coordinator answers: its store is loaded
        print(f"bench venue: starting {n} nodes …", file=sys.stderr, flush=True)
        t_start = time.monotonic()
        for s in slots:
            rig.start_node(s)
        watch = await _poll(rig, manifest.asset_id, args, t_start)
        shows = [p for p in venue_show.PARTS if p in parts]
        if shows:
            print(f"bench venue: the asset played by timeline: {', '.join(shows)} …", file=sys.stderr, flush=True)
        show = await venue_show.measure(rig, manifest.asset_id, size=args.size, fps=args.fps, cpu=cpu_seconds,
                                        parts=shows, times=venue_show.QUICK if args.quick else venue_show.Times(),
                                        budgets=budgets)
        if args.live_seconds > 0 and "live" in parts:
            print("bench venue: live frames, encoded once and streamed to every node …", file=sys.stderr, flush=True)
            show["live"] = await venue_live.measure(rig, size=args.size, fps=args.fps, seconds=args.live_seconds)
        coordinator_bps = rig.venue.coordinator_link_bps
        link_bps = rig.venue.link_bps
    finally:
        rig.close()
    live_at, ready_at = watch.live, watch.ready
    asset_bytes = manifest.total_bytes
    first_live = min(live_at.values())
    distribution = max(ready_at.values()) - first_live
    ideal = max(n * asset_bytes * 8 / coordinator_bps, asset_bytes * 8 / link_bps)
    c0, c1 = watch.coordinator_cpu
    return {
        "discovery_s": round(max(live_at.values()), 3),
        "live_s": {s: round(live_at[s], 3) for s in slots},
        "asset_bytes": asset_bytes,
        "distribution_s": round(distribution, 3),
        "distribution_ideal_s": round(ideal, 4),
        "distribution_ratio": round(distribution / ideal, 3) if distribution > 0 else None,
        "ready_s": {s: round(ready_at[s] - first_live, 3) for s in slots},
        "throughput_mbit_s": round(n * asset_bytes * 8 / distribution / 1e6, 1) if distribution > 0 else None,
        # CPU time over the distribution: the coordinator's (first node live to last ready), each
        # node's (from when it was seen live to when it was seen ready)
        "coordinator_cpu_s": round(c1 - c0, 3),
        "node_cpu_s": {s: round(watch.cpu_ready[s] - watch.cpu_live[s], 3) for s in slots},
        "decode_ms_per_frame": round(venue_show.decode_ms_per_frame(video), 2),
        **show,
    }


def _check(args) -> str | None:
    if args.nodes < 1:
        return "--nodes must be at least 1"
    if not (args.fps > 0 and args.seconds > 0 and args.poll_s > 0):
        return "--fps, --seconds and --poll-s must be > 0"
    if not 0 <= args.live_seconds <= 60:
        return "--live-seconds must be 0..60"
    if not 50 <= args.heartbeat_ms <= 60_000:
        return "--heartbeat-ms must be 50..60000"
    if any(v % 2 for v in args.size):
        return f"--size must be even in both dimensions, got {args.size[0]}x{args.size[1]}"
    if args.node_cpu is None and (args.node_gpu is not None or args.coordinator_cpu is not None or args.reserve):
        return "--node-gpu, --coordinator-cpu and --reserve go with budgets: give --node-cpu too"
    if args.keep and Path(args.keep).exists() and any(Path(args.keep).iterdir()):
        return f"--keep {args.keep}: the directory is not empty (a kept rig would already hold the asset)"
    ok, reason = available()
    if not ok:
        return f"cannot build a venue network here: {reason}"
    if args.node_cpu is not None:
        why = budgets_for(args).check()
        if why:
            return why
    return None


def budgets_for(args) -> RigBudgets:
    """The run's CPU budgets (not made yet): a group per node (and per node's rasterizer), the
    coordinator's, this process's."""
    slots = grid_names(args.nodes)
    coordinator = (args.coordinator_cpu if args.coordinator_cpu is not None
                   else coordinator_default(args.nodes, args.node_cpu, args.node_gpu))
    return RigBudgets(slots, node_cpu=args.node_cpu, node_gpu=args.node_gpu, coordinator_cpu=coordinator,
                      own=True, period_ms=args.cpu_period_ms, reserve=args.reserve, burst=args.cpu_burst)


def run(args: argparse.Namespace) -> int:
    problem = _check(args)
    if problem:
        print(f"shadowless bench venue: {problem}", file=sys.stderr)
        return 2
    if not unavailable():
        cleanup_leftovers()             # a killed run's groups, as Venue.create removes its namespaces
    budgets = budgets_for(args) if args.node_cpu is not None else None
    if budgets is not None:
        try:
            budgets.open()              # this process in its group from now on; the others as they start
        except CpuBudgetError as exc:
            print(f"shadowless bench venue: {exc}", file=sys.stderr)
            return 2
        exit_cleanup.register(budgets.close)     # removed even if this process is terminated
        print(f"bench venue: CPU budgets ({budgets.hierarchy.label}): each node {args.node_cpu:g} of a core, "
              f"its rasterizer threads {budgets.rasterizer}; the coordinator {budgets.coordinator_cpu:g}",
              file=sys.stderr, flush=True)
    workdir = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="shadowless-venue-"))
    try:
        workdir.mkdir(parents=True, exist_ok=True)
        w, h = args.size
        bit_rate = int(args.bit_rate) if args.bit_rate else default_bit_rate(args.size, args.fps)
        video = workdir / "media" / f"test-{w}x{h}-{args.fps:g}fps-{args.seconds:g}s.mp4"
        print(f"bench venue: encoding a {w}x{h} {args.fps:g} fps {args.seconds:g} s test video at "
              f"{bit_rate / 1e6:g} Mbit/s …", file=sys.stderr, flush=True)
        load_at_start = load()
        t0 = time.monotonic()
        info = make_video(video, size=args.size, fps=args.fps, seconds=args.seconds, bit_rate=bit_rate)
        print(f"bench venue: {info['bytes'] / 1e6:.1f} MB ({info['codec']}, {info['bit_rate_mbit_s']:g} Mbit/s) in "
              f"{time.monotonic() - t0:.1f} s", file=sys.stderr, flush=True)
        try:
            figures = asyncio.run(_measure(args, workdir, video, budgets))
        except VenueError as exc:
            print(f"shadowless bench venue: {exc}", file=sys.stderr)
            return 2
        except (RuntimeError, TimeoutError) as exc:     # a process died, or the nodes never got there
            print(f"shadowless bench venue: {exc}", file=sys.stderr)
            if budgets is not None:                     # what the groups took until then: starved or held?
                print(f"bench venue: {budgets.summary()}; each group: {json.dumps(budgets.stats())}; "
                      f"load {load()}", file=sys.stderr)
            return 1
        doc = {
            "benchmark": "venue",
            "machine": machine(),
            "load": {"start": load_at_start, "end": load()},   # 1, 5, 15 min: other work beside the run
            "parameters": {
                "nodes": args.nodes, "link": args.link, "coordinator_link": args.coordinator_link or args.link,
                "size": f"{w}x{h}", "output_size": "{}x{}".format(*args.output_size), "fps": args.fps,
                "seconds": args.seconds, "bit_rate": bit_rate, "codec": info["codec"],
                "video_bit_rate_mbit_s": info["bit_rate_mbit_s"], "heartbeat_ms": args.heartbeat_ms,
                "poll_s": args.poll_s, "live_seconds": args.live_seconds,
                "only": list(args.only or PARTS), "quick": args.quick,
            },
            **_limits(budgets),
            **figures,
        }
        if budgets is not None:
            doc["cpu_budget"] = {**budgets.describe(), "groups": budgets.stats()}
        if args.keep:
            doc["workdir"] = str(workdir)
        print(json.dumps(doc, indent=2))
        return 0
    finally:
        if budgets is not None:
            exit_cleanup.unregister(budgets.close)
            budgets.close()
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)


def _limits(budgets: RigBudgets | None) -> dict:
    """The budgets' limits, at the document's top level (None: no budget)."""
    if budgets is None:
        return {"node_cpu_limit": None, "node_gpu_limit": None, "coordinator_cpu_limit": None}
    d = budgets.describe()
    return {k: d[k] for k in ("node_cpu_limit", "node_gpu_limit", "coordinator_cpu_limit")}
