"""A whole rig on this machine: one coordinator process and N node processes on
127.0.0.1, with mDNS bound to the loopback interface. Used by `shadowless local`,
`shadowless bench sync`, the demo and the tests.

With a venue (``LocalRig(..., netns=True)`` or ``venue=Venue(...)``, see :mod:`shadowless.netns`)
the same processes run in network namespaces joined by a rate-limited bridge: the coordinator
listens on its venue address and advertises there, each node discovers it by real multicast
mDNS over the bridge. The process that owns the rig stays in the host's namespace, which has no
route into the venue; :meth:`LocalRig.client` reaches the coordinator through a relay that the
venue starts inside the coordinator's namespace on a Unix socket path (filesystem sockets cross
namespaces, and no interface of the host is touched). :meth:`LocalRig.run_cli` runs an operator
command inside any namespace of the venue, over the venue network.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from coordinator.api import NodeState, PlaySettings, RigStatus
from rigctl.client import OperatorError
from rigctl.link import Client
from rigctl.commands import play_dict, read_image, status_dict
from coordinator.rig import init_rig
from protos import auth
from protos import cli_types
from protos.wording import count
from shadowless import exit_cleanup
from shadowless.hold import console_lines, hold
from shadowless.process_stop import stop_process
from shadowless.netns import COORDINATOR, Venue, VenueError, available, parse_rate
from shadowless.cpu_budget import CpuBudgetError
from shadowless.rig_budget import DEFAULT_BURST, DEFAULT_PERIOD_MS, RigBudgets, parse_gpu


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def grid_names(n: int) -> list[str]:
    cols = max(1, math.ceil(math.sqrt(n)))
    return [f"r{i // cols}c{i % cols}" for i in range(n)]


class LocalRig:
    """Processes of a local rig. Use as a context manager; everything is stopped on exit.

    Parameters
    ----------
    slots:
        Slot names (one node each unless ``start_nodes=False``).
    workdir:
        Where the rig directory, logs and snapshots go.
    output_size, content_size:
        (w, h) of every projector output and of the shared content.
    clock_offsets_ms, clock_drifts_ppm:
        Per-slot test hooks that make node clocks wrong on purpose.
    node_output:
        Output spec for every node (``offscreen`` or ``room://HOST:PORT``).
    venue:
        Run every process in this :class:`~shadowless.netns.Venue` (its nodes must include every
        slot); created here if it was not yet, closed by its owner, not by the rig. Inside a venue
        the host's 127.0.0.1 is out of reach: ``room://127.0.0.1:…`` outputs do not work there.
    netns, link, coordinator_link:
        ``netns=True`` builds a venue of its own for the slots, with these link rates, and closes
        it with the rig.
    budgets:
        Open :class:`~shadowless.rig_budget.RigBudgets`: the coordinator and every node, each time
        it starts, goes into its group (closed by its owner, not by the rig).
    """

    def __init__(self, slots: list[str], workdir: Path, *, output_size=(160, 90), content_size=(160, 90),
                 clock_offsets_ms: dict[str, float] | None = None, clock_drifts_ppm: dict[str, float] | None = None,
                 node_output: str = "offscreen", snapshots: bool = False, latency_ms: float = 50.0,
                 rig_name: str | None = None, extra_node_args: dict[str, list[str]] | None = None, mdns: bool = True,
                 coordinator_args: list[str] | None = None, env: dict[str, str] | None = None,
                 venue: Venue | None = None, netns: bool = False, link: str = "1gbit",
                 coordinator_link: str | None = None, console: bool = False, budgets: RigBudgets | None = None):
        self.slots = list(slots)
        self.workdir = Path(workdir)
        self.rig_dir = self.workdir / "rig"
        self.log_dir = self.workdir / "logs"
        self.snapshot_dir = self.workdir / "snapshots" if snapshots else None
        self.output_size, self.content_size = output_size, content_size
        self.offsets = clock_offsets_ms or {}
        self.drifts = clock_drifts_ppm or {}
        self.node_output = node_output
        self.latency_ms = latency_ms
        self.rig_name = rig_name or f"local-{os.getpid()}-{int(time.time() * 1000) % 100000}"
        self.extra_node_args = extra_node_args or {}
        self.mdns = mdns
        self.coordinator_args = list(coordinator_args or [])
        self.console = console
        self.budgets = budgets       # each process started (or restarted) goes into its CPU budget's group
        self.extra_env = dict(env or {})
        self.venue = venue
        self._own_venue = venue is None and netns
        if self._own_venue:
            self.venue = Venue(self.slots, link=link, coordinator_link=coordinator_link)
        if self.venue is not None:
            missing = [s for s in self.slots if s not in self.venue.nodes]
            if missing:
                raise ValueError(f"the venue has no host for slots {missing}")
        # a venue's coordinator namespace is a fresh network stack: the usual port is free there
        self.port = 7600 if self.venue is not None else free_port()
        self.target = f"127.0.0.1:{self.port}"     # where this process reaches the coordinator
        self.coordinator: subprocess.Popen | None = None
        self.nodes: dict[str, subprocess.Popen] = {}
        self._logs: list = []

    # ---------------------------------------------------------------- lifecycle
    @property
    def coordinator_address(self) -> str:
        """The coordinator's IPv4 address as nodes see it (its venue address, or 127.0.0.1)."""
        return self.venue.address(COORDINATOR) if self.venue is not None else "127.0.0.1"

    @property
    def coordinator_target(self) -> str:
        """``HOST:PORT`` of the coordinator for processes beside the nodes."""
        return f"{self.coordinator_address}:{self.port}"

    def node_address(self, slot: str) -> str:
        return self.venue.address(slot) if self.venue is not None else "127.0.0.1"

    def create(self) -> "LocalRig":
        if self.venue is not None and self.venue.prefix is None:
            self.venue.create()
        if self.venue is not None and self.target.startswith("127.0.0.1:"):
            self.target = "unix:" + self.venue.unix_relay(COORDINATOR, self.port)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        if not (self.rig_dir / "rig.toml").exists():
            init_rig(self.rig_dir, name=self.rig_name, slots=self.slots, width=self.output_size[0],
                     height=self.output_size[1], content_width=self.content_size[0],
                     content_height=self.content_size[1], latency_ms=self.latency_ms)
        self.token = auth.read_token(self.rig_dir / "token")
        return self

    def __enter__(self) -> "LocalRig":
        try:
            self.create()
            self.started = time.monotonic()
            self.start_coordinator()
            for s in self.slots:
                self.start_node(s)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _env(self) -> dict:
        env = dict(os.environ)
        env.setdefault("LP_NUM_THREADS", "1")   # many llvmpipe contexts share two cores
        env["PYTHONUNBUFFERED"] = "1"
        env.update(self.extra_env)
        return env

    def _spawn(self, name: str, args: list[str], host: str = COORDINATOR) -> subprocess.Popen:
        """Start ``shadowless ARGS`` (in ``host``'s namespace with a venue), logging to ``name``.log."""
        log = open(self.log_dir / f"{name}.log", "ab")
        self._logs.append(log)
        argv = [sys.executable, "-m", "shadowless", *args]
        kw = dict(stdout=log, stderr=subprocess.STDOUT, env=self._env(), start_new_session=True)
        exit_cleanup.register(self.close)     # stopped even if this process is terminated
        if self.venue is not None:
            return self.venue.run(host, argv, **kw)
        return subprocess.Popen(argv, **kw)

    def start_coordinator(self) -> None:
        assert self.coordinator is None or self.coordinator.poll() is not None, "coordinator already running"
        addr = self.coordinator_address
        args = ["coordinator", "--rig", str(self.rig_dir), "--listen", f"{addr}:{self.port}"]
        args += ["--mdns-interface", addr] if self.mdns else ["--no-mdns"]
        if self.console:     # on a free port, read back by console_url
            (self.workdir / "console.port").unlink(missing_ok=True)
            args += ["--console", "127.0.0.1:0", "--console-port-file", str(self.workdir / "console.port")]
        else:
            args += ["--no-console"]
        self.coordinator = self._spawn("coordinator", args + self.coordinator_args)
        if self.budgets is not None:
            self.budgets.place("coordinator", self.coordinator.pid)

    def console_url(self, timeout: float = 30.0) -> str:
        """The operator console's address once the coordinator serves it (``console=True``)."""
        f = self.workdir / "console.port"
        deadline = time.monotonic() + timeout
        while not f.exists():
            if time.monotonic() > deadline or (self.coordinator is not None and self.coordinator.poll() is not None):
                raise RuntimeError("the coordinator serves no console:\n" + self.log("coordinator")[-2000:])
            time.sleep(0.1)
        return f"http://127.0.0.1:{int(f.read_text())}/"

    def stop_coordinator(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> None:
        if self.coordinator is not None:
            stop_process(self.coordinator, sig, timeout)

    def node_args(self, slot: str) -> list[str]:
        args = ["node", "--slot", slot, "--token-file", str(self.rig_dir / "token"), "--output", self.node_output]
        if self.mdns:
            args += ["--mdns-interface", self.node_address(slot), "--rig", self.rig_name]
        else:
            args += ["--coordinator", self.coordinator_target]
        if self.snapshot_dir is not None:
            args += ["--snapshot-dir", str(self.snapshot_dir)]
        if slot in self.offsets:
            args += ["--clock-offset-ms", str(self.offsets[slot])]
        if slot in self.drifts:
            args += ["--clock-drift-ppm", str(self.drifts[slot])]
        extra = self.extra_node_args.get(slot, [])
        if "--cache-dir" not in extra:   # each node its own asset cache, inside the rig's work directory
            args += ["--cache-dir", str(self.workdir / "caches" / slot)]
        return args + extra

    def start_node(self, slot: str, extra: list[str] | None = None) -> subprocess.Popen:
        proc = self._spawn(f"node-{slot}", self.node_args(slot) + (extra or []), host=slot)
        self.nodes[slot] = proc
        if self.budgets is not None:
            self.budgets.place(slot, proc.pid)
        return proc

    def stop_node(self, slot: str, sig: int = signal.SIGTERM, timeout: float = 10.0) -> None:
        proc = self.nodes.get(slot)
        if proc is not None:
            stop_process(proc, sig, timeout)

    def close(self) -> None:
        """Stop every process: the coordinator first, so that it ends its node sessions as closed (nodes
        stopped first would each be logged as lost by a coordinator still running), then the nodes."""
        exit_cleanup.unregister(self.close)
        self.stop_coordinator()
        for slot in list(self.nodes):
            if self.nodes[slot].poll() is None:
                self.nodes[slot].send_signal(signal.SIGTERM)
        for slot in list(self.nodes):
            self.stop_node(slot)
        self.stop_coordinator()
        for f in self._logs:
            f.close()
        self._logs.clear()
        if self._own_venue and self.venue is not None:
            self.venue.close()

    def log(self, name: str) -> str:
        f = self.log_dir / f"{name}.log"
        return f.read_text(errors="replace") if f.exists() else ""

    # ---------------------------------------------------------------- talking to it
    async def client(self, timeout: float = 30.0) -> Client:
        deadline = time.monotonic() + timeout
        while True:
            try:
                return await Client.connect(self.target, self.token)
            except Exception:
                if time.monotonic() > deadline:
                    raise
                if self.coordinator is not None and self.coordinator.poll() is not None:
                    raise RuntimeError("coordinator exited:\n" + self.log("coordinator")[-3000:])
                await asyncio.sleep(0.2)

    def run_cli(self, args: list[str], *, host: str | None = None, timeout: float = 60.0) -> str:
        """Run the operator command ``shadowless ARGS --coordinator ... --rig-dir ...`` to completion and
        return its stdout. With a venue it runs inside ``host``'s namespace (default: the
        coordinator's) and talks to the coordinator over the venue network."""
        argv = [sys.executable, "-m", "shadowless", *args, "--coordinator", self.coordinator_target,
                "--rig-dir", str(self.rig_dir)]
        if self.venue is not None:
            try:
                return self.venue.check_output(host or COORDINATOR, argv, timeout=timeout, env=self._env())
            except VenueError as exc:
                raise RuntimeError(str(exc)) from None
        r = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=self._env())
        if r.returncode != 0:
            raise RuntimeError(f"shadowless {' '.join(args)} exited with {r.returncode}: {r.stderr[-2000:]}")
        return r.stdout

    def wait_ready(self, timeout: float = 30.0) -> None:
        """Block until the coordinator answers an authenticated call."""

        async def go():
            c = await self.client(timeout)
            await c.channel.close()

        asyncio.run(go())

    async def wait_live(self, client: Client, slots: list[str] | None = None, *, timeout: float = 120.0,
                        min_joins: dict[str, int] | None = None) -> RigStatus:
        """Wait until every slot in ``slots`` is live (and has joined at least ``min_joins`` times)."""
        want = set(self.slots if slots is None else slots)
        deadline = time.monotonic() + timeout
        while True:
            st = await client.status()
            live = {n.slot for n in st.nodes if n.state == NodeState.LIVE
                    and n.joins >= (min_joins or {}).get(n.slot, 0)}
            if want <= live:
                return st
            if time.monotonic() > deadline:
                missing = sorted(want - live)
                tails = "\n".join(f"--- node {s}:\n{self.log('node-' + s)[-1500:]}" for s in missing[:3])
                raise TimeoutError(f"nodes not live after {timeout:.0f} s: {missing}\n{tails}")
            for s, p in self.nodes.items():
                if s in want and p.poll() is not None:
                    raise RuntimeError(f"node {s} exited with {p.returncode}:\n{self.log('node-' + s)[-3000:]}")
            await asyncio.sleep(0.25)


def card_image(width: int, height: int) -> np.ndarray:
    """A test image: colour ramps, a grid and a centre cross; (H, W, 3) uint16."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    img = np.stack([x / max(1, width - 1), y / max(1, height - 1), 0.5 + 0.5 * np.sin(x / 7.0) * np.cos(y / 9.0)], axis=-1)
    grid = ((x.astype(int) % 40) < 2) | ((y.astype(int) % 40) < 2)
    img[grid] = 1.0
    cy, cx = height // 2, width // 2
    img[max(0, cy - 1): cy + 2, :] = 0.0
    img[:, max(0, cx - 1): cx + 2] = 0.0
    return np.round(np.clip(img, 0, 1) * 65535).astype(np.uint16)


# ---------------------------------------------------------------- `shadowless local`
def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Start a coordinator and N offscreen nodes on 127.0.0.1 (mDNS on loopback), give each node a pose "
                     "(the identity: the whole content on every projector), show an image on all of them, play a counter "
                     "sequence, print the sync figures, and stop everything (--hold: keep the rig and its console up "
                     "until Ctrl-C). Its temporary directory (rig, token, logs, snapshots) is removed at the end "
                     "unless --keep names one.\n"
                     "With --netns the processes run on a virtual venue network instead: one network namespace per "
                     "process, joined by a rate-limited bridge, discovery by real multicast mDNS (needs root and "
                     "iproute2; see shadowless/netns.py).")
    p.epilog = ("examples:\n"
                "  shadowless local --nodes 4\n"
                "  shadowless local --nodes 4 --hold                        # then log in to the console it prints\n"
                "  sudo shadowless local --nodes 4 --netns                  # 1 Gbit/s links\n"
                "  sudo shadowless local --nodes 9 --netns --link 100mbit   # a Wi-Fi-class venue\n"
                "  sudo shadowless local --nodes 4 --node-cpu 0.4           # each node a small computer's CPU\n"
                "  python -m shadowless.netns cleanup                       # remove what a crashed run left\n"
                "  python -m shadowless.cpu_budget cleanup                  # ... and the CPU budgets' groups")
    p.add_argument("--nodes", type=cli_types.int_range(1, 256), default=4, help="how many node processes (default 4)")
    p.add_argument("--fps", type=cli_types.number(0, 1000, lo_open=True), default=30.0, help="sequence frame rate (default 30)")
    p.add_argument("--seconds", type=cli_types.number(0, 86400, lo_open=True), default=5.0, help="sequence length (default 5 s)")
    p.add_argument("--image", help="still to show first (default: a generated test card)")
    p.add_argument("--size", type=cli_types.size, default="160x90", help="projector output and content size WxH (default 160x90)")
    p.add_argument("--clock-offset-ms", type=cli_types.number(0, 1e9), default=0.0,
                   help="inject clock offsets spread over ±this many ms across the nodes (test hook; default 0: none)")
    p.add_argument("--clock-drift-ppm", type=cli_types.number(0, 10000), default=0.0, help="inject drifts spread over ±this many ppm (test hook; default 0: none)")
    p.add_argument("--keep", metavar="DIR", help="keep the rig directory, logs and snapshots in DIR")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument("--hold", action="store_true",
                   help="keep the rig and its operator console up after the figures, until Ctrl-C or SIGTERM")
    v = p.add_argument_group("virtual venue network")
    v.add_argument("--netns", action="store_true",
                   help="run every process in its own network namespace on a rate-limited bridge (root)")
    v.add_argument("--link", default="1gbit", metavar="RATE", help="with --netns: every link's rate (default 1gbit)")
    v.add_argument("--coordinator-link", metavar="RATE", help="with --netns: the coordinator's link rate (default --link)")
    b = p.add_argument_group("CPU budgets (root and a cgroup cpu controller, v1 or v2)")
    b.add_argument("--node-cpu", type=cli_types.number(0, 1024, lo_open=True), metavar="F",
                   help="hold every node process to F of a core (one cgroup each; a restarted node goes back into "
                        "it), as if each ran on a small computer of its own (default: no budget)")
    b.add_argument("--node-gpu", type=_gpu, default=None, metavar="G",
                   help="with --node-cpu: each node's rasterizer threads (llvmpipe, the GPU's stand-in) go in a "
                        "group of their own held to G of a core; 'max' (the default): no limit; 'node': they stay "
                        "in the node's budget")
    b.add_argument("--reserve", action="store_true",
                   help="with --node-cpu: give every node's, rasterizer's and the coordinator's group a high CFS "
                        "weight, so that other work on this host does not starve them (each still never gets "
                        "more than its limit; on a quiet host this changes nothing)")
    b.add_argument("--cpu-burst", type=cli_types.number(0, 1), default=DEFAULT_BURST, metavar="B",
                   help=f"with --node-cpu: each node may spend up to B of its quota more in one CFS period out of "
                        f"what it saved before (0..1, default {DEFAULT_BURST:g}; 0: none); its average stays F")
    b.add_argument("--cpu-period-ms", type=cli_types.number(1, 1000), default=DEFAULT_PERIOD_MS, metavar="MS",
                   help=f"the budgets' CFS period (default {DEFAULT_PERIOD_MS:g} ms)")


def _gpu(text: str):
    try:
        return parse_gpu(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def spread(n: int, amplitude: float, seed: int) -> list[float]:
    rng = np.random.default_rng(seed)
    return [float(v) for v in rng.uniform(-amplitude, amplitude, n)] if amplitude else [0.0] * n


def _budgets(args, slots: list[str]) -> RigBudgets | None:
    """The nodes' CPU budgets asked for (not made yet), or None."""
    if getattr(args, "node_cpu", None) is None:
        return None
    return RigBudgets(slots, node_cpu=args.node_cpu, node_gpu=args.node_gpu, period_ms=args.cpu_period_ms,
                      reserve=args.reserve, burst=args.cpu_burst)


async def _local(args) -> int:
    w, h = args.size
    try:       # the --image is read (and refused in one line) before any process starts
        picture = read_image(args.image) if args.image else None
    except OperatorError as exc:
        raise SystemExit(f"--image {exc}") from None
    if args.hold and args.netns:
        raise SystemExit("--hold serves the console on 127.0.0.1, which a --netns venue cannot reach: drop one of them")
    slots = grid_names(args.nodes)
    workdir = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="shadowless-local-"))
    remove = _Remover(None if args.keep else workdir)
    exit_cleanup.register(remove)     # registered before the rig's closer, so it runs after it
    budgets = _budgets(args, slots)
    try:
        if budgets is not None:
            budgets.open()
            exit_cleanup.register(budgets.close)      # also before the rig's closer: the groups go after the processes
        return await _run_local(args, picture, slots, workdir, (w, h), budgets)
    except CpuBudgetError as exc:
        raise SystemExit(f"shadowless local: {exc}") from None
    finally:
        if budgets is not None:
            exit_cleanup.unregister(budgets.close)
            budgets.close()
        exit_cleanup.unregister(remove)
        remove()


class _Remover:
    """Removes a temporary directory (token included) once, at the end or when the process is terminated."""

    def __init__(self, path: Path | None):
        self.path = path

    def __call__(self) -> None:
        if self.path is not None:
            shutil.rmtree(self.path, ignore_errors=True)
            self.path = None


async def give_poses(c: Client, slots: list[str]) -> str:
    """Give every slot the identity pose (content px = projector px: the rig's content and outputs have
    one size here), so each node shows the whole content instead of black; what was done, in one line."""
    for s in slots:
        await c.configure(s, homography=np.eye(3))
    return (f"poses: the identity on {count(len(slots), 'node')} (each shows the whole content; a real rig "
            "calibrates with `shadowless calibrate`)")


async def _run_local(args, picture, slots: list[str], workdir: Path, size: tuple[int, int],
                     budgets: RigBudgets | None = None) -> int:
    w, h = size
    offsets = dict(zip(slots, spread(len(slots), args.clock_offset_ms, 1)))
    drifts = dict(zip(slots, spread(len(slots), args.clock_drift_ppm, 2)))
    with LocalRig(slots, workdir, output_size=(w, h), content_size=(w, h), clock_offsets_ms=offsets,
                  clock_drifts_ppm=drifts, snapshots=True, netns=args.netns, link=args.link,
                  coordinator_link=args.coordinator_link, console=not args.netns, budgets=budgets) as rig:
        if rig.venue is not None:
            print(rig.venue.describe(), file=sys.stderr)
        # a path printed here must still be there when the operator reads it, or say that it goes
        gone = "" if args.keep or args.hold else " (removed at the end; keep them with --keep DIR)"
        print(f"rig {rig.rig_name}: coordinator on {rig.coordinator_target}, {count(len(slots), 'node')}; "
              f"logs in {rig.log_dir}{gone}", file=sys.stderr, flush=True)
        url = rig.console_url() if rig.console else ""
        if url and not args.hold:       # up only while the run lasts; its token file goes at the end unless kept
            login = (f"log in with the token in {rig.rig_dir / 'token'}" if args.keep
                     else "--hold keeps it up to log in")
            print(f"operator console: {url} until the run ends ({login})", file=sys.stderr)
        async with await rig.client() as c:
            await rig.wait_live(c)
            print(await give_poses(c, slots), file=sys.stderr, flush=True)
            img = picture if picture is not None else card_image(w, h)
            await c.show(img, name=args.image or "test card", fit="contain", persist=True)   # any aspect, whole
            await asyncio.sleep(1.0)
            frames = max(1, int(args.fps * args.seconds))
            reply = await c.play(PlaySettings(fps=args.fps, pattern="counter", frames=frames, wait=True))
            status = status_dict(await c.status())
            result = {"nodes": len(slots), "fps": args.fps, **play_dict(reply), "node_table": status["nodes"],
                      "workdir": str(workdir) if args.keep else None}
            if args.netns:
                result["venue"] = {"link": args.link, "coordinator_link": args.coordinator_link or args.link}
            if budgets is not None:
                result["cpu_budget"] = {**budgets.describe(), "groups": budgets.stats(), "summary": budgets.summary()}
            _print_result(args, result, workdir)
            if args.hold:
                then = ("every process stops" if args.keep
                        else f"every process stops and {workdir} (rig, token, logs, snapshots) is removed")
                await hold(console_lines(url, rig.rig_dir), then=then)
    return 0


def _print_result(args, result: dict, workdir: Path) -> None:
    if args.json:
        print(json.dumps(result, indent=2), flush=True)
        return
    s = result["sync"]
    print(f"{count(result['nodes'], 'node')}, {result['frames_sent']} frames at {args.fps:g} fps: shown by all "
          f"{result['frames_shown']}, late {result['frames_late']}, dropped {result['frames_dropped']}")
    if s["skew_p99_ms"] is not None:
        skew = (f"swap skew p50 {s['skew_p50_ms']} ms, p99 {s['skew_p99_ms']} ms, max {s['skew_max_ms']} ms "
                f"({s['skew_source']})")
    else:                               # skew compares nodes' swaps: None is not a figure to print
        skew = "swap skew: none (one node, nothing to compare)" if result["nodes"] == 1 else "swap skew: no data"
    clock = "-" if s["clock_error_p99_ms"] is None else f"{s['clock_error_p99_ms']} ms"
    print(f"{skew}; clock error p99 {clock}; out of order {s['out_of_order']}")
    if "cpu_budget" in result:
        print(result["cpu_budget"]["summary"])
    print(f"snapshots of the still: {workdir / 'snapshots'}" + ("" if args.keep or args.hold else
                                                                 " (removed with the rig; keep them with --keep DIR)"),
          flush=True)


def run(args: argparse.Namespace) -> int:
    if args.node_cpu is None and (args.node_gpu is not None or args.reserve):
        print("shadowless local: --node-gpu and --reserve go with budgets: give --node-cpu too", file=sys.stderr)
        return 2
    budgets = _budgets(args, grid_names(args.nodes))
    why = budgets.check() if budgets is not None else ""
    if why:            # refused before anything starts
        print(f"shadowless local: {why}", file=sys.stderr)
        return 2
    if args.netns:
        try:
            for rate in (args.link, args.coordinator_link or args.link):
                parse_rate(rate)
        except ValueError as exc:
            print(f"shadowless local: {exc}", file=sys.stderr)
            return 2
        ok, reason = available()
        if not ok:
            print(f"shadowless local --netns: {reason}", file=sys.stderr)
            return 2
    try:
        return asyncio.run(_local(args))
    except VenueError as exc:
        print(f"shadowless local: {exc}", file=sys.stderr)
        return 2
