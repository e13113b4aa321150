"""`shadowless bench venue`, part 2: the distributed asset played by timeline, a node rejoining,
and the coordinator restarted mid-show.

Three shows, one after the other, on the venue :mod:`bench.venue` built and distributed to:

* **timeline**: the asset played once (not looped) for its duration. The coordinator's sync
  tracker gives the skew (``status().sync``: over every tick it finalised; the benchmark checks
  that nothing had been tracked before the show, so these are the show's ticks), the late and
  other drops and the out-of-order count; ``frames_expected`` is the asset's frame count (the
  ticks of a show that does not loop), ``late_fraction`` = late node-frames / (ticks × nodes).
  ``coordinator_bytes_per_s_per_node`` comes from the coordinator's ``show_bytes_sent`` and
  ``frame_bytes_sent`` counters from just before the play to just after the last tick was
  settled, over that interval and the nodes (gRPC/HTTP2 framing, clock pings and the node's own
  reports are not in these counters); ``raw_bytes_per_s_per_node`` = W × H × 3 × fps of the
  video, what streaming its raw frames to each node would take.
* **rejoin**: the asset looped; after ``KILL_AFTER_S`` one node is killed (SIGKILL to its process
  group: the node process and its presenter) and started again at once. Which ticks each node swapped in is read from its log (the nodes run with
  ``SHADOWLESS_DEBUG_TIMING``, the presenter logs every swap's frame id). ``rejoin.s`` = the rig
  instant of the first tick the restarted node swapped in (``anchor_ns + k / rate``; the rig
  clock is this host's monotonic clock) minus the instant it was started. ``frame_agreement``:
  over the ticks from that first swap to the last tick a peer swapped before the stop, among the
  ticks some peer swapped, the fraction the rejoined node swapped too (a tick id fixes its frame
  index, ``anchor_frame + k`` modulo the asset's frames, so an equal id is an equal frame; a tick
  it dropped or missed counts as disagreement). ``peer_agreement`` is the same measure, over the
  same ticks, for a node that was never killed (late drops under load lower both alike).
* **coordinator_restart**: the asset looped; after ``KILL_AFTER_S`` the coordinator is killed
  (SIGKILL) and started again on the same rig directory ``OUTAGE_S`` later. ``frames_missed``:
  over every node, the ticks from 1 s before the kill to ``AFTER_REJOIN_S`` after every node was
  live again that the node did not swap in (from the nodes' logs: whatever the cause, a late drop
  under load included; the restart's own share is below), ``frames_missed_late_drops`` the part of
  them each node logged as late drops
  (its frame was not ready in time; the rest it neither swapped nor dropped); ``ticks_swapped_alone``: the ticks each node swapped while no coordinator
  ran; ``out_of_order``: swaps whose id was not above the node's previous one; ``alone_ms``: how
  long each node says it went on alone (its heartbeat); ``skew_p99_ms_after``: the restarted
  coordinator's skew over the ticks after it started, beside the first show's
  (``skew_p99_ms_before``). Where the missed ticks fall, per node: ``frames_missed_by_phase``
  (``before_kill``, ``outage``: while no coordinator ran, ``after_restart``) and
  ``missed_around_join`` (those after the restart by when they fell from the node's join: before
  it, 0-0.5 s, 0.5-1 s, 1-2 s after, later); ``rejoin_stages_ms``: ms from the restart to the
  first log line of each step of the node's rejoin (``joined``, ``clock``: its clock exchanges
  done, ``wanted``: the wanted list checked against its cache, and ``assignment`` or ``show`` only
  if the presenter took a changed one); ``cpu_ms_per_tick``: each node's CPU per tick of the show
  over the outage's last ``OUTAGE_S`` - 1 s (``alone``) and from the restart to the end of the
  window (``rejoining``): ``link``, the node process itself (the coordinator link, mDNS, fetches,
  reports), and ``node``, with its presenter (with budgets: the node's group, the rasterizer's
  threads left out, and ``throttled``, the time that group was held back by its budget);
  ``link_cpu_ms_first_s_after_join``: the node process's CPU in the first second after its join,
  less a second of its rate alone (what the rejoin itself cost it); ``restart_timeline``: from the
  restart on, in bins of ``bin_s``, the restarted coordinator's CPU (ms) and the ticks missed by
  any node, with each node's join (s), so that misses can be told from the coordinator's start-up
  (which shares this host's cores with the nodes; a venue's coordinator has a machine of its own)
  and from the nodes' rejoins. The show plays ``RESTART_BACKGROUND_S`` longer before this kill, so
  that ``background`` (node-ticks, missed, ``per_tick``: the show beside its running coordinator, from
  ``BACKGROUND_FROM_S`` after its start to the kill) gives the nodes' own rate of missed ticks;
  ``frames_missed_after_kill`` (of ``ticks_after_kill`` node-ticks, from the kill to the window's end)
  less that rate over as many ticks is ``frames_missed_restart_share``, what the restart itself cost
  (``frames_missed`` also counts the second before the kill).
"""
from __future__ import annotations

import asyncio
import math
import os
import re
import signal
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from bench.venue_throttle import ThrottleSampler, drops, miss_causes, throttles_per_s
from shadowless.local import LocalRig

#: the rejoin show: the node is killed this long after the show starts ...
KILL_AFTER_S = 3.0
#: ... and the show plays at least this long in all, and this long after the node is back in step
REJOIN_SHOW_S = 10.0
AFTER_REJOIN_S = 4.0
#: the coordinator is away this long mid-show
OUTAGE_S = 5.0
#: give up on the restarted node after this long
REJOIN_TIMEOUT_S = 60.0
#: a show's ticks are settled (every node reported, or the tracker's 3 s timeout) this long after the last
SETTLE_S = 3.5
#: the coordinator-restart show plays this much longer before its kill than KILL_AFTER_S, so that the
#: nodes' own rate of missed ticks beside a running coordinator (``background``) is measured on enough ticks
RESTART_BACKGROUND_S = 5.0
#: ... counted from this long after the show's start (its first ticks are the decoders' warm-up)
BACKGROUND_FROM_S = 1.0


@dataclass(frozen=True)
class Times:
    """How long the shows play around their kills (the defaults are the constants above)."""

    kill_after_s: float = KILL_AFTER_S
    rejoin_show_s: float = REJOIN_SHOW_S
    after_rejoin_s: float = AFTER_REJOIN_S
    outage_s: float = OUTAGE_S
    restart_background_s: float = RESTART_BACKGROUND_S


#: ``bench venue --quick``: the shows shortened for a smoke run of the benchmark itself (its
#: figures then say less: a 2.5 s outage, 1.5 s of show after each rejoin, little background)
QUICK = Times(kill_after_s=1.5, rejoin_show_s=4.0, after_rejoin_s=1.5, outage_s=2.5, restart_background_s=0.0)
#: how far ahead of now a show starts
START_DELAY_S = 0.5
SWAP = re.compile(r"timing frame (\d+): swap")
LATE = re.compile(r"timing frame (\d+): dropped \(late\)")
ENV = {"SHADOWLESS_DEBUG_TIMING": "1"}


def swapped(rig: LocalRig, slot: str, since: int, base: int, ticks: int = 10**9) -> list[int]:
    """Tick ids of the revision at ``base`` that node ``slot`` swapped in, from byte ``since`` of its log."""
    text = rig.log("node-" + slot)[since:]
    return [i for i in (int(m.group(1)) for m in SWAP.finditer(text)) if base <= i < base + ticks]


def log_sizes(rig: LocalRig) -> dict[str, int]:
    return {s: len(rig.log("node-" + s)) for s in rig.slots}


def tick_ns(state, k: int) -> int:
    """Rig instant of tick ``k`` of a show state (``anchor_ns + k / rate``, exact)."""
    return state.anchor_ns + k * state.rate_den * 1_000_000_000 // state.rate_num


def _r(x: float, nd: int = 3):
    return None if x is None or not math.isfinite(x) else round(x, nd)


def decode_ms_per_frame(video: Path, frames: int = 60) -> float:
    """Software decode of the test video to RGB on this host, one thread: ms per frame (a reference
    for the nodes, which decode the asset the same way while the others compete for the cores)."""
    import av

    with av.open(str(video)) as c:
        s = c.streams.video[0]
        s.thread_type = "NONE"
        n, t = 0, time.perf_counter()
        for f in c.decode(s):
            f.to_ndarray(format="rgb24")
            n += 1
            if n >= frames:
                break
        return (time.perf_counter() - t) * 1e3 / max(1, n)


def tree_cpu(cpu, pid: int) -> float:
    """CPU seconds of ``pid`` and its descendants (a node's presenter is a child process)."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            children.setdefault(int(stat[stat.rfind(")") + 2:].split()[1]), []).append(int(d.name))
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        c = cpu(p)
        total += 0.0 if math.isnan(c) else c
        todo += children.get(p, [])
    return total


def host_busy_s() -> float:
    """CPU seconds this host's cores have been busy (every process, from /proc/stat)."""
    f = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = f[3] + (f[4] if len(f) > 4 else 0)
    return (sum(f[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def late_per_second(rig: LocalRig, since: dict[str, int], base: int, ticks: int, fps: float) -> list[int]:
    """Late drops (node-frames) in each second of the show, from the nodes' logs."""
    late = [0] * max(1, math.ceil(ticks / fps))
    for s in rig.slots:
        for m in LATE.finditer(rig.log("node-" + s)[since[s]:]):
            k = int(m.group(1)) - base
            if 0 <= k < ticks:
                late[int(k / fps)] += 1
    return late


def _alive(rig: LocalRig) -> None:
    for s, p in rig.nodes.items():
        if p.poll() is not None:
            raise RuntimeError(f"node {s} exited with {p.returncode}:\n{rig.log('node-' + s)[-3000:]}")
    if rig.coordinator is not None and rig.coordinator.poll() is not None:
        raise RuntimeError("the coordinator exited:\n" + rig.log("coordinator")[-3000:])


def budget_delta(before: dict, after: dict, ticks: int) -> dict:
    """Each CPU budget group's CPU time, time held back and periods held back between two
    :meth:`~shadowless.rig_budget.RigBudgets.stats` readings, and its CPU per tick of the show (ms)."""
    out = {}
    for k, a in after.items():
        b = before.get(k, {})
        out[k] = {f: round(a.get(f, 0) - b.get(f, 0), 3) for f in ("cpu_s", "throttled_s", "throttled") if f in a}
        if "cpu_s" in out[k]:
            out[k]["cpu_ms_per_tick"] = round(out[k]["cpu_s"] * 1e3 / max(1, ticks), 2)
    return out


async def timeline(rig: LocalRig, c, asset_id: str, *, size: tuple[int, int], fps: float, cpu,
                   budgets=None) -> dict:
    """Play the asset once; the sync tracker's figures over its ticks, the coordinator's traffic
    (and, with ``budgets``, what each CPU budget group used and was held back over the show)."""
    n = len(rig.slots)
    before = await c.status()
    tracked_before = before.sync.frames + before.sync.frames_late + before.sync.frames_dropped
    pids = {s: p.pid for s, p in rig.nodes.items()}
    logs = log_sizes(rig)
    cpu0 = {s: tree_cpu(cpu, pid) for s, pid in pids.items()} | {"coordinator": cpu(rig.coordinator.pid)}
    host0 = host_busy_s()
    groups0 = budgets.stats() if budgets is not None else None
    t0 = time.monotonic()
    play = await c.play_asset(asset_id, delay_s=START_DELAY_S)
    duration = play.frames * play.rate_den / play.rate_num
    end_ns = tick_ns(play, play.frames)             # after the last tick
    await asyncio.sleep(max(0.0, (end_ns - time.monotonic_ns()) / 1e9))
    cpu1 = {s: tree_cpu(cpu, pid) for s, pid in pids.items()} | {"coordinator": cpu(rig.coordinator.pid)}
    host1 = host_busy_s()
    groups1 = budgets.stats() if budgets is not None else None
    busy = duration + START_DELAY_S
    await asyncio.sleep(SETTLE_S)                   # the last ticks' reports (or the tracker's timeout)
    _alive(rig)
    after = await c.status()
    t1 = time.monotonic()
    sync = after.sync
    expected = play.frames
    sent = (after.show_bytes_sent + after.frame_bytes_sent) - (before.show_bytes_sent + before.frame_bytes_sent)
    w, h = size
    return {
        "frames_expected": expected,
        "nodes": n,
        "skew_p50_ms": _r(sync.skew_p50_ms), "skew_p99_ms": _r(sync.skew_p99_ms), "skew_max_ms": _r(sync.skew_max_ms),
        "skew_source": sync.skew_source,
        "clock_error_p99_ms": _r(sync.clock_error_p99_ms),
        "frames_shown_by_all": sync.frames,
        "late": sync.frames_late,
        "late_fraction": _r(sync.frames_late / (expected * n), 4),
        "late_per_s": late_per_second(rig, logs, play.frame_id_base, expected, play.rate_num / play.rate_den),
        "dropped_other": sync.frames_dropped,
        "out_of_order": sync.out_of_order,
        "tracked_before_show": tracked_before,      # 0: the figures above are the show's ticks only
        "coordinator_bytes_sent": sent,
        "frame_bytes_sent": after.frame_bytes_sent - before.frame_bytes_sent,
        "interval_s": round(t1 - t0, 3),
        "coordinator_bytes_per_s_per_node": round(sent / (t1 - t0) / n, 1),
        "raw_bytes_per_s_per_node": round(w * h * 3 * fps),
        # CPU over the show (start delay + duration), as a share of one core (a node: with its presenter)
        "node_cpu_share": {s: _r((cpu1[s] - cpu0[s]) / busy, 2) for s in pids},
        "coordinator_cpu_share": _r((cpu1["coordinator"] - cpu0["coordinator"]) / busy, 2),
        # every core of the host (os.cpu_count()), busy on anything: the rig's processes and any other load
        "host_cpu_busy_cores": _r((host1 - host0) / busy, 2),
        "host_cpu_other_cores": _r((host1 - host0 - sum(cpu1[k] - cpu0[k] for k in cpu1)) / busy, 2),
        # with CPU budgets: each group's CPU time and time held back over the show (start delay + duration)
        **({"cpu_budget": budget_delta(groups0, groups1, expected)} if budgets is not None else {}),
    }


async def rejoin(rig: LocalRig, c, asset_id: str, times: Times = Times()) -> dict:
    """Loop the asset; kill one node mid-show and start it again; when it is back, how well it agrees."""
    victim, peers = rig.slots[-1], rig.slots[:-1]
    logs = log_sizes(rig)
    play = await c.play_asset(asset_id, loop=True, delay_s=START_DELAY_S)
    base = play.frame_id_base
    t_show = play.anchor_ns / 1e9                   # rig clock = this host's monotonic clock
    await asyncio.sleep(max(0.0, t_show + times.kill_after_s - time.monotonic()))
    _alive(rig)
    proc = rig.nodes[victim]
    # the node's whole process group (it leads its own session): the node and its presenter process,
    # as when the node's computer dies (a presenter whose node process is gone may go on swapping)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    since = len(rig.log("node-" + victim))
    t_restart, wall_restart = time.monotonic_ns(), time.time()
    rig.start_node(victim)
    first = None
    while first is None:
        ids = swapped(rig, victim, since, base)
        if ids:
            first = ids[0]
            break
        _alive(rig)
        if (time.monotonic_ns() - t_restart) / 1e9 > REJOIN_TIMEOUT_S:
            raise TimeoutError(f"node {victim} swapped no tick of the show {REJOIN_TIMEOUT_S:.0f} s after its "
                               f"restart:\n{rig.log('node-' + victim)[since:][-3000:]}")
        await asyncio.sleep(0.1)
    back_ns = tick_ns(play, first - base)
    end = max(t_show + times.rejoin_show_s, back_ns / 1e9 + times.after_rejoin_s)
    await asyncio.sleep(max(0.0, end - time.monotonic()))
    _alive(rig)
    stopped = await c.stop_show()
    await asyncio.sleep(max(0.0, (stopped.change_at_ns - time.monotonic_ns()) / 1e9) + 1.0)
    st = await c.status()
    mine = set(swapped(rig, victim, since, base))
    theirs: set[int] = set()
    for s in peers:
        theirs |= set(swapped(rig, s, logs[s], base))
    last = max(theirs) if theirs else first
    window = [t for t in range(first, last + 1) if t in theirs]
    agree = sum(1 for t in window if t in mine)
    # the same measure for a node that was never killed, over the same ticks: the baseline
    ref_window, own = [], set()
    if peers:                                       # (a lone node has no peers to agree with)
        ref, others = peers[0], set(swapped(rig, victim, since, base))
        for s in peers[1:]:
            others |= set(swapped(rig, s, logs[s], base))
        own = set(swapped(rig, ref, logs[ref], base))
        ref_window = [t for t in range(first, last + 1) if t in others]
    text = rig.log("node-" + victim)[since:]
    return {
        "node": victim,
        "s": round((back_ns - t_restart) / 1e9, 3),
        # from the restart, on the node's log (wall clock, ms): joined the coordinator, asset passed
        # to its presenter for the show
        "joined_s": _logged_after(text, "joined rig", wall_restart),
        "asset_passed_s": _logged_after(text, "passed to the presenter", wall_restart),
        "frame_agreement": _r(agree / len(window), 4) if window else None,
        "peer_agreement": _r(sum(1 for t in ref_window if t in own) / len(ref_window), 4) if ref_window else None,
        "ticks_compared": len(window),
        "ticks_missed": len(window) - agree,
        "show_s": round((stopped.change_at_ns - play.anchor_ns) / 1e9, 2),
        "out_of_order": st.sync.out_of_order,
    }


def _logged_after(text: str, what: str, wall0: float):
    """Seconds from ``wall0`` (time.time()) to the first log line containing ``what`` (None: none)."""
    for line in text.splitlines():
        if what in line:
            try:
                at = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
            except ValueError:
                return None
            return round(at - wall0, 3)
    return None


async def coordinator_restart(rig: LocalRig, asset_id: str, *, cpu=None, budgets=None, times: Times = Times()) -> dict:
    """Loop the asset; kill the coordinator (SIGKILL) mid-show and start it again ``OUTAGE_S`` later
    on the same rig directory; which ticks each node swapped in, before, during and after, where
    the missed ones fall, and what each node did and spent while it rejoined."""
    logs = log_sizes(rig)
    # when each node's budget held it back (to tell a tick missed for CPU from one missed otherwise)
    groups = {s: n.cpu.limited_stat_path() for s, n in budgets.nodes.items()
              if n.cpu.path is not None} if budgets is not None else {}
    sampler = ThrottleSampler(groups) if groups else None
    if sampler is not None:
        sampler.__enter__()
    try:
        out = await _coordinator_restart(rig, asset_id, logs, cpu=cpu, budgets=budgets, times=times,
                                         throttles=sampler)
    finally:
        if sampler is not None:
            sampler.stop()
    if sampler is not None:        # what the sampler itself took from the cores the nodes share
        out["throttle_sampler"] = {"period_ms": sampler.period_s * 1e3, "samples": sampler.samples,
                                   "cpu_ms": round(sampler.cpu_s * 1e3, 1)}
    return out


async def _coordinator_restart(rig: LocalRig, asset_id: str, logs: dict[str, int], *, cpu, budgets, times: Times,
                               throttles: ThrottleSampler | None) -> dict:
    async with await rig.client(timeout=60.0) as c:
        play = await c.play_asset(asset_id, loop=True, delay_s=START_DELAY_S)
    base, t_show = play.frame_id_base, play.anchor_ns / 1e9
    await asyncio.sleep(max(0.0, t_show + times.kill_after_s + times.restart_background_s - time.monotonic()))
    _alive(rig)
    pids = {s: p.pid for s, p in rig.nodes.items()}
    kill_ns = time.monotonic_ns()
    rig.stop_coordinator(signal.SIGKILL)
    await asyncio.sleep(1.0)                        # the nodes' own reaction to the loss settles
    alone0 = _cpu_reading(cpu, pids, budgets)
    await asyncio.sleep(times.outage_s - 1.0)
    alone1 = _cpu_reading(cpu, pids, budgets)
    back_ns, back_wall = time.monotonic_ns(), time.time()
    rig.start_coordinator()
    # CPU seconds by process from here on (the readings just before the restart first: the coordinator had none)
    samples: list[tuple[int, dict[str, float]]] = [(alone1["t"], {**alone1["link"], "coordinator": 0.0})] if alone1 else []
    sampled = {**pids, "coordinator": rig.coordinator.pid}
    sampler = asyncio.create_task(_sample_link_cpu(cpu, sampled, samples)) if cpu is not None else None
    async with await rig.client(timeout=60.0) as c:
        st = await rig.wait_live(c, timeout=REJOIN_TIMEOUT_S)
        live_ns = time.monotonic_ns()
        resumed = st.show.state == "playing" and st.show.revision == play.revision
        await asyncio.sleep(times.after_rejoin_s)
        _alive(rig)
        after_ns = time.monotonic_ns()
        back1 = _cpu_reading(cpu, pids, budgets)
        if sampler is not None:
            sampler.cancel()
            await asyncio.gather(sampler, return_exceptions=True)
        st = await c.status()                       # the restarted coordinator's tracker: ticks after its start
        stopped = await c.stop_show()
        await asyncio.sleep(max(0.0, (stopped.change_at_ns - time.monotonic_ns()) / 1e9) + 0.5)

    def tick_at(t_ns: int) -> int:                  # the tick id due at or after rig instant t_ns
        return base + math.ceil((t_ns - play.anchor_ns) * play.rate_num / (play.rate_den * 1e9))

    # every tick from 1 s before the kill to AFTER_REJOIN_S after every node was live again
    first = tick_at(kill_ns - 1_000_000_000)
    last = tick_at(live_ns + int(times.after_rejoin_s * 1e9)) - 1
    window = range(first, last + 1)
    outage = range(tick_at(kill_ns), tick_at(back_ns))
    # the show as it played beside its coordinator before the kill: the nodes' own rate of missed ticks
    background = range(tick_at(play.anchor_ns + int(BACKGROUND_FROM_S * 1e9)), outage.start)
    background_missed = 0
    missed, out_of_order, alone_ticks, phases, stages, after_join, late = {}, 0, {}, {}, {}, {}, {}
    causes: dict[str, dict[str, int]] = {}
    period_ns = int(1e9 * play.rate_den / play.rate_num)
    for s in rig.slots:
        text = rig.log("node-" + s)[logs[s]:]
        ids = [int(m.group(1)) for m in SWAP.finditer(text)]
        out_of_order += sum(1 for a, b in zip(ids, ids[1:]) if b <= a)
        got = set(ids)
        lost = [t for t in window if t not in got]
        missed[s] = len(lost)
        background_missed += sum(1 for t in background if t not in got)
        # of those, the ticks the node itself dropped as late (its frame was not ready in time: CPU),
        # the others it never swapped nor dropped (nothing scheduled them)
        dropped_late = {int(m.group(1)) for m in LATE.finditer(text)}
        late[s] = sum(1 for t in lost if t in dropped_late)
        causes[s] = miss_causes(lost, lambda t: tick_ns(play, t - base), period_ns, drops(text), throttles, s)
        alone_ticks[s] = sum(1 for t in outage if t in got)
        # where the missed ticks fall: before the kill, while no coordinator ran, after its restart
        phases[s] = {"before_kill": sum(1 for t in lost if t < outage.start),
                     "outage": sum(1 for t in lost if t in outage),
                     "after_restart": sum(1 for t in lost if t >= outage.stop)}
        stages[s] = rejoin_stages(text, back_wall, play.revision)
        joined = stages[s].get("joined")
        if joined is not None:
            # the missed ticks after the restart, by when they fell from the node's join (rig clock)
            join_ns = back_ns + int(joined * 1e6)
            after_join[s] = _bins([(tick_ns(play, t - base) - join_ns) / 1e9 for t in lost if t >= outage.stop])
    nodes = {n.slot: n for n in st.nodes}
    out = {
        "outage_s": round((back_ns - kill_ns) / 1e9, 3),
        "back_s": round((live_ns - back_ns) / 1e9, 3),   # from the restart until every node was live again
        "show_taken_back": resumed,
        "ticks_in_window": len(window),
        "frames_missed": sum(missed.values()),
        **restart_share(background_missed, len(background) * len(rig.slots), phases,
                        (last + 1 - outage.start) * len(rig.slots)),
        "frames_missed_by_node": missed,
        "frames_missed_late_drops": late,
        # why: its budget held the node back just before the tick, its decoder was late, or neither
        "frames_missed_causes": causes,
        "frames_missed_by_phase": phases,
        "missed_around_join": after_join,
        "rejoin_stages_ms": stages,
        "ticks_during_outage": len(outage),
        "ticks_swapped_alone": alone_ticks,
        "out_of_order": out_of_order,
        "alone_ms": {s: round(nodes[s].show.alone_ms) for s in rig.slots},
        # the restarted coordinator's sync figures, over the ticks after it started
        "skew_p99_ms_after": _r(st.sync.skew_p99_ms), "skew_max_ms_after": _r(st.sync.skew_max_ms),
        "frames_after": st.sync.frames,
    }
    if throttles is not None:
        lo, hi = tick_ns(play, first - base), tick_ns(play, last - base)
        out["throttles_per_s"] = {s: throttles_per_s(throttles, s, lo, hi) for s in rig.slots}
    if cpu is not None:
        # each node's CPU (ms per tick) alone (the outage's last OUTAGE_S - 1 s) and from the restart to the
        # end of the window: the node process itself ("link") and with its presenter ("node")
        ticks_alone = (alone1["t"] - alone0["t"]) * play.rate_num / play.rate_den / 1e9
        ticks_back = (after_ns - back_ns) * play.rate_num / play.rate_den / 1e9
        out["cpu_ms_per_tick"] = {
            "alone": _cpu_per_tick(alone0, alone1, ticks_alone),
            "rejoining": _cpu_per_tick(alone1, back1, ticks_back),
        }
        # the node process's CPU in the first second after its join, less a second of its rate alone:
        # what the rejoin itself cost it (ms)
        alone_ms_per_s = {s: (alone1["link"][s] - alone0["link"][s]) * 1e12 / max(1, alone1["t"] - alone0["t"])
                          for s in pids}
        # from the restart on, in bins of TIMELINE_BIN_S: the restarted coordinator's CPU and the ticks
        # missed by any node (whether the misses follow the coordinator's start-up or the nodes' joins)
        bins = max(1, math.ceil((after_ns - back_ns) / (TIMELINE_BIN_S * 1e9)))
        missed_bins = [0] * bins
        for s in rig.slots:
            got = set(int(m.group(1)) for m in SWAP.finditer(rig.log("node-" + s)[logs[s]:]))
            for t in window:
                k = int((tick_ns(play, t - base) - back_ns) // (TIMELINE_BIN_S * 1e9))
                if t not in got and 0 <= k < bins:
                    missed_bins[k] += 1
        out["restart_timeline"] = {
            "bin_s": TIMELINE_BIN_S,
            "coordinator_cpu_ms": [_r(_cpu_between(samples, "coordinator", back_ns + int(k * TIMELINE_BIN_S * 1e9),
                                                   int(TIMELINE_BIN_S * 1e9)), 0) for k in range(bins)],
            "missed": missed_bins,
            "joined_s": {s: _r(stages[s]["joined"] / 1e3, 2) if "joined" in stages[s] else None for s in rig.slots},
        }
        out["link_cpu_ms_first_s_after_join"] = {
            s: _r(_cpu_between(samples, s, back_ns + int(stages[s]["joined"] * 1e6), 1_000_000_000)
                  - alone_ms_per_s[s], 1) if "joined" in stages[s] else None for s in pids}
    return out


def restart_share(background_missed: int, background_ticks: int, phases: dict[str, dict[str, int]],
                  ticks_after_kill: int) -> dict:
    """What the restart itself cost, beside ``frames_missed`` (which counts the second before the kill too):
    ``background`` (node-ticks, missed, missed per tick) over the show before the kill, from
    BACKGROUND_FROM_S after its start, the nodes' own rate beside a running coordinator;
    ``frames_missed_after_kill`` of ``ticks_after_kill`` (node-ticks from the kill to the window's end);
    ``frames_missed_restart_share``: those less the background rate over as many ticks (may be below 0)."""
    rate = background_missed / background_ticks if background_ticks else None
    after = sum(p["outage"] + p["after_restart"] for p in phases.values())
    return {
        "background": {"ticks": background_ticks, "missed": background_missed,
                       "per_tick": None if rate is None else round(rate, 5)},
        "ticks_after_kill": ticks_after_kill,
        "frames_missed_after_kill": after,
        "frames_missed_restart_share": None if rate is None else round(after - rate * ticks_after_kill, 1),
    }


#: the bins of ``restart_timeline`` (seconds)
TIMELINE_BIN_S = 0.5
#: bins of ``missed_around_join``: seconds from a node's join to a missed tick's instant
JOIN_BINS = ((-math.inf, 0.0, "before"), (0.0, 0.5, "0-0.5s"), (0.5, 1.0, "0.5-1s"), (1.0, 2.0, "1-2s"),
             (2.0, math.inf, "later"))


def _bins(offsets: list[float]) -> dict[str, int]:
    return {name: sum(1 for x in offsets if lo <= x < hi) for lo, hi, name in JOIN_BINS}


async def _sample_link_cpu(cpu, pids: dict[str, int], samples: list, period_s: float = 0.05) -> None:
    """Every ``period_s`` until cancelled: (monotonic ns, each process's CPU seconds, by name) into ``samples``."""
    while True:
        samples.append((time.monotonic_ns(), {s: cpu(p) for s, p in pids.items()}))
        await asyncio.sleep(period_s)


def _cpu_between(samples: list, name: str, t0: int, span_ns: int) -> float:
    """CPU ms of process ``name`` over [t0, t0 + span_ns], from the last sample at or before its start
    and the first at or after its end, scaled to the span (NaN when the samples do not reach both
    ends, or lie more than twice the span apart: this process was starved of CPU itself)."""
    before = [(t, c[name]) for t, c in samples if t <= t0]
    after = [(t, c[name]) for t, c in samples if t >= t0 + span_ns]
    if not before or not after:
        return math.nan
    (ta, a), (tb, b) = before[-1], after[0]
    if tb - ta > 2 * span_ns:
        return math.nan
    return (b - a) * 1e3 * span_ns / max(1, tb - ta)


def _cpu_reading(cpu, pids: dict[str, int], budgets) -> dict:
    """CPU seconds now of each node process alone (its link side: ``link``) and with its presenter
    (``node``: with budgets, the node's group, the rasterizer's threads left out, and that group's time
    held back, ``throttled``; without, the process tree, rasterizer included), and the monotonic
    instant."""
    if cpu is None:
        return {}
    r = {"t": time.monotonic_ns(), "link": {s: cpu(p) for s, p in pids.items()}}
    if budgets is not None:
        stats = budgets.stats()
        r["node"] = {s: stats.get(f"node {s}", {}).get("cpu_s", 0.0) for s in pids}
        r["throttled"] = {s: stats.get(f"node {s}", {}).get("throttled_s", 0.0) for s in pids}
    else:
        r["node"] = {s: tree_cpu(cpu, p) for s, p in pids.items()}
    return r


def _cpu_per_tick(a: dict, b: dict, ticks: float) -> dict:
    return {k: {s: _r((b[k][s] - a[k][s]) * 1e3 / max(ticks, 1e-9), 2) for s in a[k]} for k in a if k != "t"}


def rejoin_stages(text: str, wall0: float, revision: int) -> dict:
    """ms from ``wall0`` (the coordinator's restart, time.time()) to the first log line of each
    rejoin step after it (a step not logged is left out): joined, the clock exchanges done, the
    wanted list checked against the cache, and only if the presenter took them again, a changed
    assignment (pose, LUT, gain) or the show's ``revision`` as a new one."""
    steps = {"joined": re.compile("joined rig"), "clock": re.compile("clock burst"),
             "wanted": re.compile("the rig wants"),
             "assignment": re.compile(r"node\.presenter: assignment r\d+: \w+ pose,"),
             "show": re.compile(rf"node\.presenter: timeline r{revision}:")}
    out = {}
    for step, what in steps.items():
        for line in text.splitlines():
            if not what.search(line):
                continue
            try:
                at = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
            except ValueError:
                continue
            if at >= wall0:
                out[step] = round((at - wall0) * 1e3)
                break
    return out


#: the shows this module plays, in order (``bench venue --only`` picks some)
PARTS = ("timeline", "rejoin", "restart")


async def measure(rig: LocalRig, asset_id: str, *, size, fps, cpu, budgets=None, parts=PARTS,
                  times: Times = Times()) -> dict:
    out = {}
    async with await rig.client(timeout=60.0) as c:
        if "timeline" in parts:
            out["timeline"] = await timeline(rig, c, asset_id, size=size, fps=fps, cpu=cpu, budgets=budgets)
        if "rejoin" in parts:
            try:
                out["rejoin"] = await rejoin(rig, c, asset_id, times)
            except TimeoutError as exc:     # a starved node never catches up: say so, and measure the rest
                out["rejoin"] = {"node": rig.slots[-1], "failed": str(exc).splitlines()[0]}
                await c.stop_show()
    if "restart" in parts:
        restart = await coordinator_restart(rig, asset_id, cpu=cpu, budgets=budgets, times=times)
        if "timeline" in out:
            restart["skew_p99_ms_before"] = out["timeline"]["skew_p99_ms"]
        out["coordinator_restart"] = restart
    return out
