"""`shadowless swarm`: many protocol-level nodes in one process, to load a coordinator before a show.

Each swarm node is a real client of the rig (:mod:`shadowless.swarm_node`): it finds the
coordinator (mDNS or ``--coordinator``), proves the rig token, joins its slot, keeps a clock
estimate from pings, follows its assignments, fetches its share of the wanted assets, follows the
show's timeline and receives live frames, and reports heartbeats, swaps and drops as a node does;
it only does not render. So a coordinator can be loaded with hundreds of nodes from one machine
and watched with ``shadowless status`` (the swarm's slots show ``live``, their swaps feed the
sync figures) or measured with ``shadowless bench swarm``.

All nodes share one asyncio loop and one timer (swaps are due at the same instants), each with a
session, streams, clock estimate and TCP connection of its own (``--share-connection`` multiplexes
them on one, which costs the coordinator less than real nodes do). Assets: fetching a 2 GB show 256 times from one
machine tests the disk, not the coordinator, so by default each node fetches the manifest of every
wanted asset and one of its blobs (node *i* takes blob *i* mod the blob count, so the swarm as a
whole fetches every blob), checks it against its SHA-256 and keeps nothing; it then reports the
asset ready. ``--fetch all`` fetches every blob on every node (a distribution test),
``--fetch manifest`` none.

The swarm reports what it did (``--json``, ``--stats-file``): joins, swaps reported and how many
were on time (a swap the swarm wakes up for later than ``--late-ms`` after its instant is reported
as a late drop, as a real node would drop it), its own CPU time.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import resource
import signal
import sys
import time
from dataclasses import asdict
from pathlib import Path

from protos import cli_types
from protos.auth import TokenError, read_token, resolve_token
from protos.discovery import Discovery, DiscoveryError, NothingAdvertised
from shadowless.swarm_config import FETCH_MODES, SwarmConfig, SwarmStats
from shadowless.swarm_node import SwarmNode, Ticker

log = logging.getLogger("shadowless.swarm")
#: seconds between the writes of ``--stats-file`` (a bench reads it at each end of a measured window)
STATS_S = 0.25


class Swarm:
    """N swarm nodes on this process's event loop: ``await run(seconds)`` or ``start()``/``stop()``."""

    def __init__(self, cfg: SwarmConfig):
        self.cfg = cfg
        self.stats = SwarmStats()
        self.nodes: list[SwarmNode] = []
        self._stopping: asyncio.Event | None = None
        self._tasks: list[asyncio.Task] = []
        self._discovery: Discovery | None = None
        self._found: list[str] = []
        self._found_at = -1e9
        self._find_lock: asyncio.Lock | None = None
        self._ticker: Ticker | None = None
        self._cpu0 = 0.0
        self._t0 = 0.0

    async def _targets(self) -> list[str]:
        """Where the coordinator is: --coordinator, or mDNS (one lookup shared by every node that asks
        within a few seconds, so hundreds of nodes do not flood the network with queries)."""
        if self.cfg.coordinator is not None:
            return [self.cfg.coordinator]
        async with self._find_lock:
            if self._found and time.monotonic() - self._found_at < 5.0:
                return list(self._found)
            self._found = await self._discover()
            self._found_at = time.monotonic()
            return list(self._found)

    async def _discover(self) -> list[str]:
        if self._discovery is None:
            self._discovery = Discovery(interfaces=self.cfg.mdns_interfaces)
            await self._discovery.start()
        ads = await self._discovery.find(rig=self.cfg.rig, timeout=3.0)
        if len({a.rig_id for a in ads}) > 1:
            names = ", ".join(sorted(f"{a.name} ({a.rig_id})" for a in ads))
            raise DiscoveryError(f"several rigs are advertised ({names}); pick one with --rig NAME")
        if not ads:
            raise NothingAdvertised(self._discovery.nothing_found(3.0, self.cfg.rig) +
                                    "; still looking (or pass --coordinator)")
        return [a.target for a in ads]

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        self._find_lock = asyncio.Lock()
        self._ticker = Ticker(loop)
        self._cpu0, self._t0 = _cpu_s(), time.monotonic()
        join_gate = asyncio.Semaphore(self.cfg.join_concurrency)
        fetch_gate = asyncio.Semaphore(self.cfg.fetch_concurrency)
        self.nodes = [SwarmNode(slot, i, self.cfg, self.stats, self._ticker, self._targets, join_gate, fetch_gate)
                      for i, slot in enumerate(self.cfg.slots)]
        self._tasks = [asyncio.create_task(n.run(self._stopping), name=f"swarm:{n.slot}") for n in self.nodes]

    async def stop(self) -> None:
        if self._stopping is not None:
            self._stopping.set()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._ticker is not None:
            self._ticker.close()
        if self._discovery is not None:
            await self._discovery.close()
            self._discovery = None

    @property
    def live(self) -> int:
        return sum(1 for n in self.nodes if n.joined)

    def summary(self) -> dict:
        """The swarm's figures: counters, how many swaps were on time, its own CPU and memory."""
        s = asdict(self.stats)
        hist = s.pop("late_hist")
        wall = max(1e-9, time.monotonic() - self._t0)
        cpu = _cpu_s() - self._cpu0
        due = self.stats.swaps + self.stats.woke_late
        return {
            "nodes": len(self.nodes), "live": self.live, **s,
            "on_time_fraction": round(self.stats.swaps / due, 5) if due else None,
            "swap_wake_late_ms_hist": dict(zip(["<0.5", "<1", "<2", "<4", "<8", "<16", "<32", ">=32"], hist)),
            "late_ms": self.cfg.late_ms, "fetch": self.cfg.fetch, "ping_hz": self.cfg.ping_hz,
            "ping_settled_s": self.cfg.ping_settled_s, "report_batch_ms": self.cfg.report_batch_ms,
            "timeline_batch_ms": self.cfg.timeline_batch_ms, "heartbeat_ms": self.cfg.heartbeat_ms,
            "own_connections": self.cfg.own_connections,
            "wall_s": round(wall, 3), "cpu_s": round(cpu, 3), "cpu_fraction_of_core": round(cpu / wall, 4),
            "rss_mb": round(_rss_mb(), 1), "pid": os.getpid(),
        }

    async def run(self, seconds: float | None = None, *, stats_file: Path | None = None,
                  stop: asyncio.Event | None = None) -> dict:
        """Run until ``seconds`` passed or ``stop`` is set; the summary (written to ``stats_file``
        every :data:`STATS_S` seconds on the way)."""
        await self.start()
        stop = stop or asyncio.Event()
        deadline = None if seconds is None else time.monotonic() + seconds
        try:
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                if stats_file is not None:
                    _write_json(stats_file, self.summary())
                try:    # not wait_for: on 3.11 it drops a cancel that meets the set stop event
                    async with asyncio.timeout(STATS_S if deadline is None else
                                               max(0.01, min(STATS_S, deadline - time.monotonic()))):
                        await stop.wait()
                except TimeoutError:
                    pass
        finally:
            await self.stop()
        out = self.summary()
        if stats_file is not None:
            _write_json(stats_file, out)
        return out


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _rss_mb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:  # pragma: no cover - not Linux
        pass
    return 0.0


def _write_json(path: Path, doc: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc))
    os.replace(tmp, path)


def default_slots(n: int) -> list[str]:
    """``r{row}c{col}`` names of a square-ish grid of ``n`` slots, as ``rig init --grid`` names them."""
    cols = 1
    while cols * cols < n:
        cols += 1
    return [f"r{i // cols}c{i % cols}" for i in range(n)]


# ---------------------------------------------------------------- `shadowless swarm`
def _settled_s(text: str) -> float:
    """--ping-settled-s: 0 (pings at --ping-hz always, as a node before it settled its exchanges:
    ``bench swarm --rates dense``) or 1 to 60 seconds."""
    value = cli_types.number(0, 60)(text)
    if 0 < value < 1:
        raise argparse.ArgumentTypeError(f"'{text}' is neither 0 nor a number from 1 to 60")
    return value


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Load-test a coordinator before a show: run N protocol-level nodes in this one process. Each discovers the "
        "coordinator, proves the rig token, joins its slot, keeps a clock estimate, fetches its share of the wanted "
        "assets, follows the timeline and live frames and reports heartbeats and swaps like a real node, without "
        "rendering anything. Watch the coordinator meanwhile (`shadowless status`, its CPU), or let "
        "`shadowless bench swarm` measure it.\n\n"
        "The rig must have a slot for every swarm node: make a test rig (`shadowless rig init DIR --grid 16x16`), "
        "run a coordinator on it, and point the swarm at it with --rig-dir DIR (token and slots from there). Run "
        "the swarm on another machine than the coordinator when you can: hundreds of swarm nodes use a core or more.")
    p.epilog = (
        "examples:\n"
        "  shadowless rig init /tmp/loadtest --grid 16x16 --resolution 1920x1080\n"
        "  shadowless coordinator --rig /tmp/loadtest &\n"
        "  shadowless swarm --nodes 256 --rig-dir /tmp/loadtest --seconds 120 --json\n"
        "  shadowless swarm --nodes 64 --token-file token --coordinator 10.0.0.2:7600 --slot-prefix s   # slots s0..s63\n"
        "\nwhat it prints (at the end, or in --stats-file four times a second): joins, swaps reported, on_time_fraction "
        "(swaps\nthe swarm woke up for within --late-ms; the others are reported as late drops), its own CPU time.")
    p.add_argument("--nodes", type=cli_types.int_range(1, 100_000), required=True, help="how many swarm nodes")
    where = p.add_argument_group("which rig")
    where.add_argument("--rig-dir", type=Path, metavar="DIR",
                       help="the rig directory: its token, and its first N slots for the nodes")
    where.add_argument("--token-file", metavar="FILE", help="rig token file (default: $SHADOWLESS_TOKEN_FILE)")
    where.add_argument("--slots", type=cli_types.names, metavar="A,B,...", help="slot names for the nodes (default: the rig's, or r0c0…)")
    where.add_argument("--slot-prefix", metavar="P", help="slots P0 … P{N-1}")
    where.add_argument("--coordinator", metavar="HOST:PORT", help="skip mDNS and use this coordinator")
    where.add_argument("--rig", metavar="NAME", help="with several rigs advertised, join this one (name or id)")
    where.add_argument("--mdns-interface", action="append", metavar="IP",
                       help="browse mDNS on this IPv4 address only (repeatable; default all)")
    how = p.add_argument_group("what each node does")
    how.add_argument("--fetch", choices=FETCH_MODES, default="one",
                     help="assets: the manifest and one blob per node (default), every blob, or the manifest only")
    how.add_argument("--ping-hz", type=cli_types.number(0.1, 100), default=4.0,
                     help="clock pings per second per node until its clock is settled (default 4, as a node)")
    how.add_argument("--ping-settled-s", type=_settled_s, default=10.0, metavar="S",
                     help="then one ping every S seconds (default 10, as a node; 0: --ping-hz always)")
    how.add_argument("--report-batch-ms", type=cli_types.number(0, 10000), default=50.0,
                     help="swaps and drops of streamed frames are batched over this long (default 50, as a node)")
    how.add_argument("--timeline-batch-ms", type=cli_types.number(0, 60000), metavar="MS",
                     help="those of timeline ticks wait up to this long, going with the heartbeat when it is due "
                          "by then (default: the heartbeat interval, as a node; 50 sends them as streamed frames' are)")
    how.add_argument("--heartbeat-ms", type=cli_types.number(50, 60000), metavar="MS",
                     help="heartbeat interval (default: what the coordinator asks for, rig.toml's heartbeat_ms)")
    how.add_argument("--share-connection", action="store_true",
                     help="multiplex every node on one TCP connection (default: one connection per node, as real "
                          "nodes have; sharing costs the coordinator less)")
    how.add_argument("--late-ms", type=cli_types.number(0, 10000), default=10.0,
                     help="a swap the swarm wakes up for later than this is reported as a late drop (default 10)")
    how.add_argument("--clock-offset-ms", type=cli_types.number(0, 1e9), default=0.0, help="give node clocks random offsets within ±this (default 0: none)")
    how.add_argument("--clock-drift-ppm", type=cli_types.number(0, 10000), default=0.0, help="give node clocks random drifts within ±this (default 0: none)")
    out = p.add_argument_group("how long and what to print")
    out.add_argument("--seconds", type=cli_types.number(0, 1e7, lo_open=True), help="stop after this long (default: until Ctrl-C or SIGTERM)")
    out.add_argument("--stats-file", type=Path, metavar="FILE", help="write the figures here as JSON four times a second")
    out.add_argument("--json", action="store_true", help="print the final figures as JSON")


def config_from_args(args: argparse.Namespace) -> SwarmConfig:
    """The swarm's configuration from the command line; ValueError/TokenError say what is wrong."""
    n = args.nodes
    if n < 1:
        raise ValueError(f"--nodes must be at least 1, got {n}")
    rig_slots: list[str] | None = None
    rig_name = args.rig
    if args.rig_dir is not None:
        from coordinator.rig import RigError, parse_config
        toml = args.rig_dir / "rig.toml"
        try:
            conf = parse_config(toml.read_text(), source=str(toml))
        except FileNotFoundError:
            raise ValueError(f"{args.rig_dir} is not a rig directory (no rig.toml; create one with "
                             "`shadowless rig init DIR --grid 16x16`)") from None
        except RigError as exc:
            raise ValueError(str(exc)) from None
        rig_slots = list(conf.slots)
        rig_name = rig_name or conf.name
    token = read_token(args.rig_dir / "token") if args.rig_dir is not None and not args.token_file \
        else resolve_token(args.token_file)
    if args.slots:
        slots = list(args.slots)
    elif args.slot_prefix:
        slots = [f"{args.slot_prefix}{i}" for i in range(n)]
    elif rig_slots is not None:
        slots = rig_slots
    else:
        slots = default_slots(n)
    if len(slots) < n:
        raise ValueError(f"{n} swarm nodes need {n} slots, the rig has {len(slots)}; make a test rig with enough "
                         f"(`shadowless rig init DIR --grid 16x16`)")
    return SwarmConfig(slots=slots[:n], token=token, coordinator=args.coordinator, rig=rig_name,
                       mdns_interfaces=args.mdns_interface, fetch=args.fetch, ping_hz=args.ping_hz,
                       ping_settled_s=args.ping_settled_s or None, report_batch_ms=args.report_batch_ms,
                       timeline_batch_ms=args.timeline_batch_ms, late_ms=args.late_ms, heartbeat_ms=args.heartbeat_ms,
                       own_connections=not args.share_connection,
                       clock_offset_ms=args.clock_offset_ms,
                       clock_drift_ppm=args.clock_drift_ppm)


async def _main(cfg: SwarmConfig, args: argparse.Namespace) -> dict:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    swarm = Swarm(cfg)
    print(f"swarm: {len(cfg.slots)} nodes ({cfg.slots[0]} … {cfg.slots[-1]}) joining "
          f"{cfg.coordinator or 'the coordinator found over mDNS'}", file=sys.stderr, flush=True)
    return await swarm.run(args.seconds, stats_file=args.stats_file, stop=stop)


def run(args: argparse.Namespace) -> int:
    try:
        cfg = config_from_args(args)
    except (ValueError, TokenError) as exc:
        print(f"shadowless swarm: {exc}", file=sys.stderr)
        return 2
    summary = asyncio.run(_main(cfg, args))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{summary['nodes']} swarm nodes, {summary['joins']} joins: {summary['swaps']} swaps reported, "
              f"{summary['late']} late, on time {summary['on_time_fraction']}; swarm CPU {summary['cpu_s']} s "
              f"over {summary['wall_s']} s")
    return 0
