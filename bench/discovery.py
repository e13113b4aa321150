"""`shadowless bench discovery`: real nodes find their rig while rogue coordinators advertise.

In each run, two rogue coordinators advertise over mDNS (on 127.0.0.1) from the start: a
*twin*, with this rig's name and id but another token (an impersonator, or a rig restored
from a backup with a fresh token), and an *other* rig. Then the rig's own coordinator
starts, and N real node processes (offscreen outputs) start as the shipped deployment
files run them: unpinned (``--rig`` empty; ``--pin id`` pins them to the rig's id). A
node joins only a coordinator that proves it knows the node's token, so both rogues must
be passed over.

Measured per run, on this host's monotonic clock, polling the right coordinator's status
every 0.1 s: ``all_live_s`` (from starting the node processes until every node is live
on the right coordinator) and each node's ``live_s``; ``within_15s`` (nodes live within
15 s); ``tried_rogue`` (nodes whose log shows they asked a rogue, which could not prove the
token); ``captured`` (nodes live on a rogue at the end: must be 0). With ``--control``
(default), the same N nodes also join with no rogue advertising, in the same run, and
``rogue_cost`` is the ratio of the two times: what the rogues cost, free of this machine's
start-up time for N interpreters and GL contexts.

``--prime-other K``: K nodes start believing they last joined the *other* rig (its id in
their cache), so they try it first: a deterministic rogue attempt.

``--hostile before|after`` measures something else: a *hostile* advertiser
(``bench/mdns_hostile.py``) claims the rig's mDNS instance name without conflict probing and
points at a tarpit (a port that accepts and never answers), from before the coordinator starts
(which then renames itself, RFC 6762 §9) or from after it advertised (two responders, one name).
On an mDNS service of the run's own, on loopback and/or in a virtual venue network (``--where``;
the hostile on a venue host of its own), N unpinned nodes start; per trial:
``joined``/``started``, ``joined_within_10s``, ``join_s`` p50/max (from starting the node
processes until live), ``ready_to_join_s`` (from each node's renderer being up to its join, from
its log: discovery and handshake alone), ``timed_out_on_hostile`` (nodes whose Hello to the
tarpit ran out), ``operator_found_rig`` (``shadowless status --rig-dir`` over mDNS reached the
rig's own coordinator, the hostile advertising), and with ``--control`` the same nodes with no
hostile (``control_join_s``, ``hostile_cost_max`` = max over control max).

``--name-clash K`` (loopback): K times, two rigs with the same name start their coordinators one
after the other, ``--clash-nodes`` nodes of the first running meanwhile; ``renamed`` (the second
advertises as another instance name), ``logged_rename`` and ``both_found`` (a browser finds both
rig ids under the rig's name) count the starts.
"""
from __future__ import annotations

import argparse
import asyncio
import datetime
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench.machine import machine
from bench.workdir import run_dir
from coordinator.api import NodeState
from coordinator.rig import parse_config
from protos import auth
from protos.discovery import Discovery
from shadowless.local import LocalRig, grid_names
from shadowless.netns import Venue, VenueError
from shadowless.netns import available as netns_available
from shadowless.process_stop import stop_process

SIZE = (32, 18)
NOT_TRUSTED_MARK = "could not prove it knows the rig token"
#: the venue host the hostile advertiser runs on
ROGUE = "rogue"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=int, default=16, help="node processes per run (default 16)")
    p.add_argument("--runs", type=int, default=5, help="runs (default 5)")
    p.add_argument("--pin", choices=("none", "id"), default="none",
                   help="run the nodes unpinned (none, default) or with --rig RIG_ID")
    p.add_argument("--prime-other", type=int, default=0, metavar="K",
                   help="K nodes start believing they last joined the other rig (default 0)")
    p.add_argument("--control", action=argparse.BooleanOptionalAction, default=True,
                   help="also time the same nodes joining with no rogue (default on)")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for every node (default 120)")
    p.add_argument("--workdir", help="keep the rigs and logs here (default: a temporary folder, removed)")
    p.add_argument("--hostile", choices=("before", "after"),
                   help="instead: a hostile advertiser claims the rig's mDNS name without probing, from before the "
                        "coordinator starts (it renames itself) or after it advertised (two responders, one name)")
    p.add_argument("--name-clash", type=int, default=0, metavar="K",
                   help="instead: K times, two rigs of the same name start their coordinators one after the other: "
                        "does the second rename itself, are both found (default 0: off)")
    p.add_argument("--clash-nodes", type=int, default=4, metavar="M",
                   help="with --name-clash: nodes of the first rig running when the second starts (default 4)")
    p.add_argument("--where", choices=("loopback", "venue", "both"), default="both",
                   help="with --hostile: on loopback, in a virtual venue network, or both (default)")


def _rig(workdir: Path, slots: list[str]) -> LocalRig:
    return LocalRig(slots, workdir, output_size=SIZE, content_size=SIZE, mdns=True)


async def _wait_all_live(rig: LocalRig, t0: float, timeout: float) -> dict[str, float]:
    """Seconds from ``t0`` at which each slot was first seen live (polled every 0.1 s)."""
    live: dict[str, float] = {}
    deadline = t0 + timeout
    async with await rig.client(timeout=60) as c:
        while len(live) < len(rig.slots) and time.monotonic() < deadline:
            st = await c.status()
            now = time.monotonic() - t0
            for n in st.nodes:
                if n.state is NodeState.LIVE and n.slot not in live:
                    live[n.slot] = now
            await asyncio.sleep(0.1)
    return live


async def _live_slots(rig: LocalRig) -> list[str]:
    async with await rig.client(timeout=30) as c:
        return [n.slot for n in (await c.status()).nodes if n.state is NodeState.LIVE]


def _wait_logs(rig: LocalRig, slots: list[str], mark: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not all(mark in rig.log("node-" + s) for s in slots):
        dead = [s for s in slots if rig.nodes[s].poll() is not None]
        if dead or time.monotonic() > deadline:
            raise RuntimeError(f"nodes {dead or slots} never logged {mark!r}: "
                               + rig.log("node-" + (dead or slots)[0])[-2000:])
        time.sleep(0.1)


def trial(workdir: Path, n: int, *, rogues: bool, pin: str = "none", prime_other: int = 0,
          timeout: float = 120.0, real_late: bool = False) -> dict:
    """One run: N nodes join their rig's coordinator (with the two rogues advertising when
    ``rogues``). Returns the figures described in the module docstring. ``real_late``: the rig's
    own coordinator starts only once every node has asked a rogue (and been turned away), the
    worst case of a rogue answering first."""
    slots = grid_names(n)
    real = _rig(workdir / "real", slots).create()
    twin = other = None
    started: list[LocalRig] = []
    try:
        cfg = parse_config((real.rig_dir / "rig.toml").read_text())
        if rogues:
            twin = _rig(workdir / "twin", slots)
            twin.rig_dir.mkdir(parents=True)
            shutil.copy(real.rig_dir / "rig.toml", twin.rig_dir / "rig.toml")
            (twin.rig_dir / "token").write_text(auth.new_token() + "\n")    # the same rig, another token
            (twin.rig_dir / "token").chmod(0o600)
            twin.create()
            twin.rig_name = cfg.name
            other = _rig(workdir / "other", slots).create()
            for r in (twin, other):
                r.start_coordinator()
                started.append(r)
            for r in (twin, other):
                r.wait_ready()
        if not real_late:
            real.start_coordinator()
            started.append(real)
            real.wait_ready()
        other_id = parse_config((other.rig_dir / "rig.toml").read_text()).rig_id if other else ""
        extra = ["--rig", cfg.rig_id if pin == "id" else ""]
        for i, s in enumerate(slots):
            if other_id and i < prime_other:
                cache = real.workdir / "caches" / s
                cache.mkdir(parents=True, exist_ok=True)
                (cache / "joined-rig").write_text(other_id + "\n")
        t0 = time.monotonic()
        for s in slots:
            real.start_node(s, extra)
        if real_late:
            _wait_logs(real, slots, NOT_TRUSTED_MARK, timeout)
            real.start_coordinator()
            started.append(real)
        live = asyncio.run(_wait_all_live(real, t0, timeout))
        captured = []
        for r in (twin, other):
            if r is not None:
                captured += asyncio.run(_live_slots(r))
        tried = [s for s in slots if NOT_TRUSTED_MARK in real.log("node-" + s)]
        known = {s: (real.workdir / "caches" / s / "joined-rig").read_text().strip()
                 if (real.workdir / "caches" / s / "joined-rig").exists() else "" for s in slots}
        return {
            "nodes": n,
            "joined": len(live),
            "all_live_s": round(max(live.values()), 3) if len(live) == n else None,
            "live_s": {s: round(v, 3) for s, v in sorted(live.items())},
            "within_15s": sum(1 for v in live.values() if v <= 15.0),
            "tried_rogue": len(tried),
            "tried_rogue_slots": tried,
            "captured": len(captured),
            "remembered_rig": sum(1 for v in known.values() if v == cfg.rig_id),
        }
    finally:
        for r in [real, *started]:
            r.close()


def _advertised_name(rig: LocalRig, timeout: float = 30.0) -> str:
    """The instance name the rig's coordinator advertises (from its log's 'advertising NAME on' line)."""
    deadline = time.monotonic() + timeout
    while True:
        m = re.search(r"advertising (\S+) on \S+ port \d+", rig.log("coordinator"))
        if m:
            return m.group(1)
        if time.monotonic() > deadline or (rig.coordinator is not None and rig.coordinator.poll() is not None):
            raise RuntimeError("the coordinator never said what it advertises:\n" + rig.log("coordinator")[-2000:])
        time.sleep(0.1)


def _start_hostile(rig: LocalRig, venue: Venue | None, name: str, rig_id: str, service: str) -> subprocess.Popen:
    """bench.mdns_hostile claiming ``name`` (the rig's or its coordinator's instance name) without probing,
    on 127.0.0.1 or from the venue's ``rogue`` host; returns once it advertises."""
    interface = venue.address(ROGUE) if venue is not None else "127.0.0.1"
    argv = [sys.executable, "-m", "bench.mdns_hostile", "--interface", interface, "--name", name,
            "--rig-id", rig_id, "--service", service]
    with open(rig.log_dir / "hostile.log", "ab") as err:     # the child keeps its own copy
        kw = dict(stdout=subprocess.PIPE, stderr=err, text=True, env=rig._env(), start_new_session=True)
        proc = venue.run(ROGUE, argv, **kw) if venue is not None else subprocess.Popen(argv, **kw)
    line = proc.stdout.readline()
    if not line.startswith("{"):
        proc.kill()
        proc.wait()
        raise RuntimeError("the hostile advertiser did not start: " + rig.log("hostile")[-2000:])
    return proc


def _ready_to_join_s(log: str) -> float | None:
    """Seconds from a node's renderer being up (its 'rendering with' line) to its first join (the
    'joined rig' line), from the log's timestamps: what discovery and the handshake cost, free of the
    node's start-up (an interpreter and a GL context, seconds on a loaded machine)."""
    stamps = {}
    for mark in ("rendering with", "joined rig"):
        m = re.search(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) .*" + mark, log, re.M)
        if m is None:
            return None
        stamps[mark] = datetime.datetime.strptime(m.group(1), "%Y-%m-%d %H:%M:%S,%f")
    return max(0.0, (stamps["joined rig"] - stamps["rendering with"]).total_seconds())


def _operator_finds(rig: LocalRig, venue: Venue | None, host: str, rig_id: str) -> bool:
    """Whether ``shadowless status --rig-dir`` over mDNS (from ``host``'s namespace in a venue) reaches the
    rig's own coordinator (its id in the answer), the hostile advertising all the while."""
    argv = [sys.executable, "-m", "shadowless", "status", "--json", "--rig-dir", str(rig.rig_dir),
            "--mdns-interface", rig.node_address(host)]
    try:
        if venue is not None:
            out = venue.check_output(host, argv, timeout=60, env=rig._env())
        else:
            out = subprocess.run(argv, capture_output=True, text=True, timeout=60, env=rig._env(), check=True).stdout
        return json.loads(out)["rig"]["id"] == rig_id
    except (subprocess.SubprocessError, VenueError, ValueError, KeyError) as exc:
        print(f"shadowless bench discovery: the operator's status failed: {exc}", file=sys.stderr)
        return False


def hostile_trial(workdir: Path, n: int, *, venue: bool = False, when: str = "after", timeout: float = 60.0,
                  service: str | None = None) -> dict:
    """N real nodes (unpinned) join their rig while a hostile advertiser claims the rig's instance name without
    probing (bench.mdns_hostile: a tarpit behind it). ``when``: "before" the coordinator starts (the
    coordinator renames itself) or "after" it advertised (the hostile takes its very name: two
    responders, one instance name); "none": no hostile (the control: this machine's start-up time).
    ``venue``: on a virtual venue network (the hostile on a host of its own) instead of loopback.
    ``service``: an mDNS service of the trial's own (default: one derived from this process's id, so
    that other rigs on the machine neither see nor disturb it).
    """
    if when not in ("before", "after", "none"):
        raise ValueError(f"when must be 'before', 'after' or 'none', not {when!r}")
    slots = grid_names(n)
    service_name = service or f"_slh-{os.getpid() % 10 ** 6}"
    service_type = f"{service_name}._tcp.local."
    v = Venue([*slots, ROGUE]) if venue else None
    real = LocalRig(slots, workdir, output_size=SIZE, content_size=SIZE, mdns=True, venue=v,
                    env={"SHADOWLESS_MDNS_SERVICE": service_name})
    hostile = None
    try:
        real.create()
        cfg = parse_config((real.rig_dir / "rig.toml").read_text())
        if when == "before":
            hostile = _start_hostile(real, v, cfg.name, cfg.rig_id, service_type)
        real.start_coordinator()
        real.wait_ready(60)
        advertised = _advertised_name(real)
        if when == "after":
            hostile = _start_hostile(real, v, advertised.removesuffix("." + service_type), cfg.rig_id, service_type)
        t0 = time.monotonic()
        for s in slots:
            real.start_node(s, ["--rig", ""])
        live = asyncio.run(_wait_all_live(real, t0, timeout))
        times = sorted(live.values())
        operator = _operator_finds(real, v, slots[0], cfg.rig_id)
        tarpit = [s for s in slots if "DEADLINE_EXCEEDED" in real.log("node-" + s)]
        after_ready = sorted(t for t in (_ready_to_join_s(real.log("node-" + s)) for s in slots) if t is not None)
        return {
            "where": "venue" if venue else "loopback",
            "hostile": when,
            "advertised_as": advertised,
            "renamed": advertised != f"{cfg.name}.{service_type}",
            "started": n,
            "joined": len(live),
            "joined_within_10s": sum(1 for t in times if t <= 10.0),
            "join_s": {"p50": round(statistics.median(times), 3), "max": round(times[-1], 3)} if times else None,
            "live_s": {s: round(t, 3) for s, t in sorted(live.items())},
            "ready_to_join_s": {"p50": round(statistics.median(after_ready), 3), "max": round(after_ready[-1], 3)}
            if after_ready else None,
            "timed_out_on_hostile": len(tarpit),
            "operator_found_rig": operator,
            "coordinator_saw_hostile": "another mDNS responder answers for this coordinator's name"
                                       in real.log("coordinator"),
        }
    finally:
        if hostile is not None:
            stop_process(hostile)
            hostile.stdout.close()
        real.close()
        if v is not None:
            v.close()


def clash_trial(workdir: Path, *, nodes: int = 4, service: str | None = None) -> dict:
    """Two rigs with the same name, their coordinators started one after the other on loopback (on an
    mDNS service of the trial's own), the first one's ``nodes`` nodes running meanwhile (more processes
    sharing port 5353, as on a rig's network): what each advertises as, whether the second renamed
    itself, and whether a browser finds both (by the rig name in TXT, each with its own id)."""
    service_name = service or f"_slc-{os.getpid() % 10 ** 6}"
    service_type = f"{service_name}._tcp.local."
    name = f"clash-{os.getpid()}-{int(time.time() * 1000) % 100000}"
    rigs = [LocalRig(grid_names(max(1, nodes)), workdir / k, output_size=SIZE, content_size=SIZE, rig_name=name,
                     env={"SHADOWLESS_MDNS_SERVICE": service_name}) for k in ("first", "second")]
    try:
        names = []
        for r in rigs:
            r.create()
            r.start_coordinator()
            r.wait_ready(60)
            names.append(_advertised_name(r))
            if r is rigs[0] and nodes:
                for slot in r.slots[:nodes]:
                    r.start_node(slot)
                asyncio.run(_wait_all_live(r, time.monotonic(), 120))
        ids = {parse_config((r.rig_dir / "rig.toml").read_text()).rig_id for r in rigs}

        async def browse() -> set[str]:
            disc = Discovery(interfaces=["127.0.0.1"], service_type=service_type)
            await disc.start()
            try:
                deadline = time.monotonic() + 10
                found: set[str] = set()
                while time.monotonic() < deadline and found != ids:
                    found = {a.rig_id for a in await disc.find(rig=name, timeout=5, settle=0.5)}
                return found
            finally:
                await disc.close()

        found = asyncio.run(browse())
        return {"advertised_as": names, "renamed": names[1] != names[0],
                "logged_rename": "is already answered for" in rigs[1].log("coordinator"),
                "both_found": found == ids}
    finally:
        for r in rigs:
            r.close()


def _run_clash(args: argparse.Namespace) -> int:
    trials = []
    with run_dir(args.workdir, "discovery-clash") as work:
        for k in range(args.name_clash):
            rec = clash_trial(Path(work) / f"start{k + 1}", nodes=args.clash_nodes)
            print(f"start {k + 1}: {rec['advertised_as']} renamed={rec['renamed']} both found={rec['both_found']}",
                  file=sys.stderr)
            trials.append(rec)
    out = {
        "benchmark": "discovery",
        "mode": "name-clash",
        "params": {"starts": args.name_clash, "clash_nodes": args.clash_nodes},
        "machine": machine(),
        "renamed": sum(t["renamed"] for t in trials),
        "logged_rename": sum(t["logged_rename"] for t in trials),
        "both_found": sum(t["both_found"] for t in trials),
        "starts": len(trials),
        "trials": trials,
    }
    print(json.dumps(out, indent=2))
    return 0 if all(t["renamed"] and t["both_found"] for t in trials) else 1


def _run_hostile(args: argparse.Namespace) -> int:
    trials = []
    wheres = {"loopback": [False], "venue": [True], "both": [False, True]}[args.where]
    with run_dir(args.workdir, "discovery-hostile") as work:
        for k in range(args.runs):
            for venue in wheres:
                if venue:
                    ok, reason = netns_available()
                    if not ok:
                        print(f"shadowless bench discovery: no virtual venue here ({reason}); loopback only",
                              file=sys.stderr)
                        continue
                where = "venue" if venue else "loopback"
                rec = hostile_trial(Path(work) / f"run{k + 1}" / where, args.nodes, venue=venue, when=args.hostile,
                                    timeout=args.timeout)
                rec["run"] = k + 1
                if args.control:   # the same nodes, no hostile, side by side: what the hostile costs
                    ctl = hostile_trial(Path(work) / f"run{k + 1}" / f"{where}-control", args.nodes, venue=venue,
                                        when="none", timeout=args.timeout)
                    rec["control_join_s"] = ctl["join_s"]
                    if rec["join_s"] and ctl["join_s"]:
                        rec["hostile_cost_max"] = round(rec["join_s"]["max"] / ctl["join_s"]["max"], 3)
                print(f"run {k + 1} {rec['where']}: {rec['joined']}/{rec['started']} joined, "
                      f"{rec['joined_within_10s']} within 10 s, {rec['join_s']} (control {rec.get('control_join_s')})",
                      file=sys.stderr)
                trials.append(rec)
    summary = {}
    for where in ("loopback", "venue"):
        ts = [t for t in trials if t["where"] == where]
        if not ts:
            continue
        times = sorted(t for tr in ts for t in tr["live_s"].values())
        costs = [t["hostile_cost_max"] for t in ts if t.get("hostile_cost_max")]
        ready = sorted(t["ready_to_join_s"]["max"] for t in ts if t.get("ready_to_join_s"))
        summary[where] = {
            "joined": sum(t["joined"] for t in ts), "started": sum(t["started"] for t in ts),
            "joined_within_10s": sum(t["joined_within_10s"] for t in ts),
            "join_s": {"p50": round(statistics.median(times), 3), "max": round(times[-1], 3)} if times else None,
            "hostile_cost_max_median": round(statistics.median(costs), 3) if costs else None,
            "ready_to_join_max_s": ready[-1] if ready else None,
        }
    out = {
        "benchmark": "discovery",
        "mode": "hostile",
        "params": {"nodes": args.nodes, "runs": args.runs, "hostile": args.hostile, "where": args.where,
                   "timeout": args.timeout, "control": args.control},
        "machine": machine(),
        "summary": summary,
        "trials": trials,
    }
    print(json.dumps(out, indent=2))
    return 0 if all(t["joined"] == t["started"] for t in trials) else 1


def run(args: argparse.Namespace) -> int:
    if args.nodes < 1 or args.runs < 1 or args.name_clash < 0 or args.clash_nodes < 0:
        print("shadowless bench discovery: --nodes and --runs must be at least 1, --name-clash and --clash-nodes "
              "at least 0", file=sys.stderr)
        return 2
    if args.name_clash:
        return _run_clash(args)
    if args.hostile:
        return _run_hostile(args)
    runs = []
    with run_dir(args.workdir, "discovery") as work:
        for k in range(args.runs):
            rec = {"run": k + 1}
            rec["rogues"] = trial(Path(work) / f"run{k + 1}" / "rogues", args.nodes, rogues=True, pin=args.pin,
                                  prime_other=args.prime_other, timeout=args.timeout)
            if args.control:
                rec["control"] = trial(Path(work) / f"run{k + 1}" / "control", args.nodes, rogues=False,
                                       pin=args.pin, timeout=args.timeout)
                a, b = rec["rogues"]["all_live_s"], rec["control"]["all_live_s"]
                rec["rogue_cost"] = round(a / b, 3) if a and b else None
            print(f"run {k + 1}: {rec['rogues']['joined']}/{args.nodes} joined, all live in "
                  f"{rec['rogues']['all_live_s']} s (control {rec.get('control', {}).get('all_live_s')} s), "
                  f"{rec['rogues']['tried_rogue']} tried a rogue, {rec['rogues']['captured']} captured",
                  file=sys.stderr)
            runs.append(rec)
    times = [r["rogues"]["all_live_s"] for r in runs if r["rogues"]["all_live_s"] is not None]
    costs = [r["rogue_cost"] for r in runs if r.get("rogue_cost")]
    out = {
        "benchmark": "discovery",
        "params": {"nodes": args.nodes, "runs": args.runs, "pin": args.pin, "prime_other": args.prime_other,
                   "control": args.control},
        "machine": machine(),
        "runs_all_joined_within_15s": sum(1 for r in runs if r["rogues"]["within_15s"] == args.nodes),
        "all_live_s": {"median": round(statistics.median(times), 3), "max": round(max(times), 3)} if times else None,
        "rogue_cost_median": round(statistics.median(costs), 3) if costs else None,
        "captured_total": sum(r["rogues"]["captured"] for r in runs),
        "runs": runs,
    }
    print(json.dumps(out, indent=2))
    return 0 if all(r["rogues"]["joined"] == args.nodes and r["rogues"]["captured"] == 0 for r in runs) else 1
