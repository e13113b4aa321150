"""What one blend switch costs each process of a rig, outside the failover's detection: a small repeatable rig.

A P25 failover's CPU (:mod:`bench.uniformity_cpu`) mixes the detection, the coordinator's pushes and every
node's redraw; this isolates the switch itself. ``n`` node processes (offscreen output, a 320x200 still, no
room) join a coordinator in this process; the coordinator then sets new blend maps on every slot for one
common instant, as :meth:`coordinator.blending.state.BlendState._switch` does for a failover (two sets of
maps in turn, float16-packed as a variant's are), ``switches`` times, one every ``period_s``. The CPU each
group ran over those switches, less what it ran over as long a time with no switch (heartbeats, the
presenters' "alive"), is divided by the number of switches and of nodes: CPU per switch per node
(network side, presenter) and per switch (this process: the coordinator and the script's own polling).

Each switch's way is also read from the nodes' logs (their line of the first swap with the maps, as
:mod:`bench.uniformity_live` reads a failover's): how long after the instant the last node showed them
(``last_after_instant_ms``, 0 when every node was on time), when each node's network side had its
assignment after the coordinator set them all (``set_to_received``), and how long before the instant each
frame was rendered. ``--rig P25`` runs the failover's rig less its lost node (24 node processes, the
coordinator's assignments in slot order) and ``--room`` sends every node's frames to a ``shadowless room``
process as the failover's do, so that a P25 failover's switch can be repeated many times on one rig:
``python -m bench.uniformity_switch --rig P25 --room --lead-ms 80 --switches 20`` (about 1.5 minutes).
``--node-env K=V`` starts the nodes with that environment (A/B of a node setting in the same minutes).

Run: ``python -m bench.uniformity_switch --nodes 4 --switches 20 [--profile-dir DIR]``. With
``--profile-dir``, every presenter writes a cProfile of its whole life there
(``SHADOWLESS_PROFILE_DIR``, :mod:`node.presenter_process`), every node's network side too (it is
started through :mod:`bench.uniformity_profiled`), and the coordinator's event loop over the switches.
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.uniformity_cpu import CpuSnapshot, children_of

__all__ = ["measure"]

SIZE = (320, 200)          # the table room's projector (P25)
MAP_SIZE = (80, 50)        # a failover variant's maps for it (coarser than the projector)


def _maps(seed: int):
    from protos.blend import BlendMaps
    rng = np.random.default_rng(seed)
    w, h = MAP_SIZE
    alpha = rng.uniform(0.3, 1.0, (h, w, 3)).astype(np.float32)
    beta = rng.uniform(0.0, 0.05, (h, w)).astype(np.float32)
    return BlendMaps(alpha, beta).packed()


def _add(into: dict, d: dict) -> None:
    for k, v in d.items():
        if isinstance(v, (int, float)):
            into[k] = round(into.get(k, 0.0) + v, 2)
        elif isinstance(v, dict):
            _add(into.setdefault(k, {}), v)


def _snapshot(local, me: int) -> tuple[CpuSnapshot, ...]:
    """The groups' run times, with this process's threads; one node's and its presenter's threads apart."""
    nodes = [p.pid for p in local.nodes.values() if p.poll() is None]
    first = nodes[0]
    return (CpuSnapshot({"network": nodes, "presenters": [c for p in nodes for c in children_of(p)],
                         "coordinator": [me]}, threads_of=me),
            CpuSnapshot({}, threads_of=first), CpuSnapshot({}, threads_of=(children_of(first) or [first])[0]))


def _since(b, a) -> dict:
    out = b[0].since(a[0])
    out["node_threads"] = b[1].since(a[1]).get("threads", {})
    out["presenter_threads"] = b[2].since(a[2]).get("threads", {})
    return out


async def _until(pred, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        await asyncio.sleep(0.01)


def _switch_way(local, slots: list[str], at: int, set_ns: int) -> dict:
    """One switch's way to the screens, from the nodes' log lines of their first swap with its maps (those
    whose instant is ``at``): the last node's delay past the instant, the assignments' arrivals after the
    coordinator set them (``set_ns``), in slot order, and the renders' margins before the instant (ms)."""
    from bench.uniformity_live import _TIMING
    shown, received, margin = [], {}, []
    for s in slots:
        rows = [m for m in _TIMING.finditer(local.log(f"node-{s}")) if int(m.group(3)) == at]
        if not rows:
            continue
        m = rows[-1]
        shown.append(int(m.group(2)))
        received[s] = round((int(m.group(4)) - set_ns) / 1e6, 1)
        if m.group(8) and int(m.group(8)):
            margin.append((at - int(m.group(8))) / 1e6)
    if not shown:
        return {}
    return {"nodes": len(shown), "last_after_instant_ms": round(max(0, max(shown) - at) / 1e6, 2),
            "late_nodes": sum(1 for v in shown if v - at > 1_000_000),
            "received_max_ms": max(received.values()), "received_p50_ms": float(np.median(list(received.values()))),
            "rendered_before_instant_min_ms": round(min(margin), 2) if margin else None,
            "set_to_received_by_slot": received}


def _summary(ways: list[dict], lead_ms: float, frame_ms: float) -> dict:
    """Over the switches: the last node's delay past the instant and the last arrival (p50, max), and what a
    failover with this lead would score (lead plus the last delay, in frames)."""
    ways = [w for w in ways if w]
    if not ways:
        return {}
    last = [w["last_after_instant_ms"] for w in ways]
    recv = [w["received_max_ms"] for w in ways]
    frames = [(lead_ms + v) / frame_ms for v in last]
    return {"switches_read": len(ways), "last_after_instant_ms": {"p50": round(float(np.median(last)), 2),
                                                                  "max": round(max(last), 2)},
            "received_max_ms": {"p50": round(float(np.median(recv)), 2), "max": round(max(recv), 2)},
            "late_nodes_p50": float(np.median([w["late_nodes"] for w in ways])),
            "frames_at_lead": {"p50": round(float(np.median(frames)), 2), "max": round(max(frames), 2),
                               "within_3": sum(1 for f in frames if f <= 3.0)}}


async def measure(n: int, switches: int, work: Path, *, period_s: float = 1.0, lead_ms: float = 150.0,
                  profile_dir: Path | None = None, rig: str | None = None, room: bool = False,
                  node_env: dict[str, str] | None = None, fps: float = 30.0) -> dict:
    from shadowless.local import grid_names

    if rig:
        from bench.uniformity_scenes import slots_of
        every = slots_of(rig)
        lost = "r2c2" if "r2c2" in every else every[len(every) // 2]
        slots = [s for s in every if s != lost]        # a failover's: the lost node's process is gone
    else:
        slots = grid_names(n)
    env = {"SHADOWLESS_PROFILE_DIR": str(profile_dir)} if profile_dir else {}
    env.update(node_env or {})
    with contextlib.ExitStack() as stack:
        output = "offscreen"
        if room:
            from types import SimpleNamespace
            from bench.uniformity_live import room_process
            from bench.uniformity_scenes import Light
            address, _pid = stack.enter_context(room_process(
                SimpleNamespace(projector_scale=0.25, camera_scale=0.25, seed=0), Light(), work / "room", slots))
            output = f"room://{address}"
        return await _measure(slots, switches, work, period_s=period_s, lead_ms=lead_ms, profile_dir=profile_dir,
                              env=env, output=output, fps=fps, rig_name=rig, room=room)


async def _measure(slots: list[str], switches: int, work: Path, *, period_s: float, lead_ms: float,
                   profile_dir: Path | None, env: dict, output: str, fps: float, rig_name: str | None,
                   room: bool) -> dict:
    from coordinator.app import CoordinatorApp
    from coordinator.rig import HomographyPose, Rig
    from shadowless.local import LocalRig

    n = len(slots)
    local = LocalRig(slots, work, output_size=SIZE, content_size=SIZE, mdns=False, latency_ms=200.0, env=env,
                     node_output=output)
    if profile_dir:
        profile_dir.mkdir(parents=True, exist_ok=True)
        spawn = local._spawn

        def profiled(name, args, host="coordinator"):
            if args and args[0] == "node":      # the network side through the profiling wrapper
                import subprocess
                log = open(local.log_dir / f"{name}.log", "ab")
                local._logs.append(log)
                return subprocess.Popen([sys.executable, "-m", "bench.uniformity_profiled", *args], stdout=log,
                                        stderr=subprocess.STDOUT, env=local._env(), start_new_session=True)
            return spawn(name, args, host)
        local._spawn = profiled
    local.create()
    rig = Rig(local.rig_dir)
    maps = [_maps(1), _maps(2)]
    lut = np.tile(np.linspace(0, 1, 1024, dtype=np.float32), (3, 1))    # a failover's assignment carries one
    for s in slots:
        rig.update_slot(s, pose=HomographyPose(np.eye(3)), lut=lut)
    app = CoordinatorApp(Rig(local.rig_dir), local.token, listen=f"127.0.0.1:{local.port}", advertise=False)
    await app.start()
    core = app.coordinator
    for s in slots:      # the rig's blend as a blend job leaves it (not in rig.toml)
        core.update_slot(s, blend=maps[0], blend_at_ns=0, source="blend")
    out: dict = {"nodes": n, "switches": switches, "period_s": period_s, "lead_ms": lead_ms, "rig": rig_name,
                 "room": room, "node_env": {k: v for k, v in env.items() if k != "SHADOWLESS_PROFILE_DIR"}}
    ways: list[dict] = []
    try:
        for s in slots:
            local.start_node(s)
        async with await local.client() as c:
            await local.wait_live(c, timeout=300)
            white = np.full((SIZE[1], SIZE[0], 3), 65535, np.uint16)
            await c.show(white, name="flat white")

            def showing(m) -> bool:
                return all((sess := core.by_slot.get(s)) is not None and sess.blend_id == m.blend_id for s in slots)
            await _until(lambda: showing(maps[0]), 30, "every node showing the first maps")
            await asyncio.sleep(2.0)         # the show's and the join's trailing work
            me = os.getpid()
            prof = None
            if profile_dir:
                import cProfile
                prof = cProfile.Profile()
            idle: dict = {}
            busy: dict = {}
            late = 0
            for i in range(switches):
                # a window with no switch, then one with a switch, as long: background work (heartbeats, the
                # clock's pings, "alive") that fades after the nodes joined weighs on both alike
                a = await asyncio.to_thread(_snapshot, local, me)
                await asyncio.sleep(period_s)
                b = await asyncio.to_thread(_snapshot, local, me)
                _add(idle, _since(b, a))
                t0 = time.monotonic()
                if prof is not None:
                    prof.enable()
                m = maps[(i + 1) % 2]
                at = core.clock_ns() + int(lead_ms * 1e6)
                for s in slots:
                    core.update_slot(s, blend=m, blend_at_ns=at, source="blend")
                set_ns = core.clock_ns()
                await _until(lambda: showing(m), 30, f"switch {i}: every node showing its maps")
                late += sum(1 for s in slots if core.by_slot[s].blend_since_rig_ns > at + 1_000_000)
                ways.append(await asyncio.to_thread(_switch_way, local, slots, at, set_ns))
                await asyncio.sleep(max(0.0, t0 + period_s - time.monotonic()))
                if prof is not None:
                    prof.disable()
                c2 = await asyncio.to_thread(_snapshot, local, me)
                _add(busy, _since(c2, b))
            if prof is not None:
                prof.dump_stats(str(profile_dir / f"coordinator-{me}.prof"))
        scale = busy["span_ms"] / idle["span_ms"]
        per = {}
        for k in ("network", "presenters", "coordinator"):
            extra = busy[k] - idle[k] * scale
            per[k] = round(extra / switches / (n if k != "coordinator" else 1), 3)
        out["way"] = _summary(ways, lead_ms, 1e3 / fps)
        out["switch_ways"] = ways
        out.update({"per_switch_per_node_ms": {"network": per["network"], "presenter": per["presenters"]},
                    "coordinator_per_switch_ms": per["coordinator"], "late_node_switches": late,
                    "busy": busy, "idle": idle,
                    **{f"{g}_extra_ms": {k: round(v - idle.get(g, {}).get(k, 0.0) * scale, 1)
                                         for k, v in busy.get(g, {}).items()}
                       for g in ("threads", "node_threads", "presenter_threads")}})
    finally:
        local.close()
        await app.stop()
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--nodes", type=int, default=4)
    p.add_argument("--switches", type=int, default=20)
    p.add_argument("--period-s", type=float, default=1.0)
    p.add_argument("--lead-ms", type=float, default=150.0)
    p.add_argument("--profile-dir", type=Path)
    p.add_argument("--rig", help="a named rig less its centre node, as a failover leaves it (P25: 24 nodes)")
    p.add_argument("--room", action="store_true", help="the nodes' frames go to a `shadowless room` process")
    p.add_argument("--node-env", action="append", default=[], metavar="K=V", help="the nodes' environment")
    p.add_argument("--fps", type=float, default=30.0, help="the frame rate the lead is counted in")
    p.add_argument("--work", type=Path)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="shadowless-switch-") as tmp:
        work = args.work or Path(tmp)
        env = dict(kv.split("=", 1) for kv in args.node_env)
        out = asyncio.run(measure(args.nodes, args.switches, work, period_s=args.period_s, lead_ms=args.lead_ms,
                                  profile_dir=args.profile_dir, rig=args.rig, room=args.room, node_env=env,
                                  fps=args.fps))
    out["load"] = os.getloadavg()
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
