"""`shadowless bench preauth`: what unauthenticated messages under the size cap cost the coordinator.

Start a coordinator process and ``--nodes`` real node processes on loopback, wait until every
node is live, then fire ``--calls`` concurrent unauthenticated calls of ``--size-mib`` MiB each
(below the coordinator's 4 MiB message limit) at ``--method`` from a separate process over
``--channels`` connections. Meanwhile:

* the coordinator's resident memory is sampled from ``/proc/PID/status`` (``VmRSS``) every 10 ms;
  ``rss_peak_mib`` is the largest sample, ``rss_after_mib`` the value ``--settle`` seconds after
  the burst ended;
* an operator who logged in before the burst asks ``status`` again and again
  (``status_max_s``: the slowest answer);
* afterwards every node must still be live on its first join, and the coordinator's log lines
  written during the burst are counted (``log_lines``, ``tracebacks``).

The attack's calls end with a status code each (``codes``). Prints one JSON document.
"""
from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench.machine import load, machine
from bench.workdir import run_dir
from coordinator.api import NodeState
from coordinator.wire.serve import BUDGET_OFF_ENV
from shadowless.local import LocalRig, grid_names

MIB = 1024 * 1024


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--calls", type=int, default=400, help="concurrent unauthenticated calls (default 400)")
    p.add_argument("--size-mib", type=float, default=3.0, help="each call's message, MiB (default 3; the limit is 4)")
    p.add_argument("--channels", type=int, default=8, help="connections the calls are spread over (default 8)")
    p.add_argument("--nodes", type=int, default=2, help="real node processes that must stay live (default 2)")
    p.add_argument("--method", default="/shadowless.v1.NodeLink/Hello",
                   help="the unauthenticated method called (default /shadowless.v1.NodeLink/Hello)")
    p.add_argument("--payload", choices=("garbage", "hello"), default="garbage",
                   help="garbage: bytes that are no message (default); hello: a HelloRequest with a huge slot name")
    p.add_argument("--settle", type=float, default=3.0, help="seconds after the burst before rss_after (default 3)")
    p.add_argument("--compare", action="store_true",
                   help="measure first without the budget for calls before authentication (the coordinator as it "
                        "was before it), then with it, side by side")
    p.add_argument("--keep", metavar="DIR", help="keep the rig and its logs in DIR/preauth")


def _rss_kib(pid: int, key: str = "VmRSS:") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key):
            return int(line.split()[1])
    return 0


class _Sampler(threading.Thread):
    """Samples a process's VmRSS every ``period`` s until stopped; the largest sample in ``peak_kib``."""

    def __init__(self, pid: int, period: float = 0.01):
        super().__init__(daemon=True)
        self.pid, self.period, self.peak_kib, self.samples = pid, period, 0, 0
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                self.peak_kib = max(self.peak_kib, _rss_kib(self.pid))
            except OSError:
                return
            self.samples += 1
            self.stop.wait(self.period)




async def _status_probe(client, stop: threading.Event, times: list[float]) -> None:
    while not stop.is_set():
        t0 = time.monotonic()
        async with asyncio.timeout(30):
            await client.status()
        times.append(time.monotonic() - t0)
        await asyncio.sleep(0.05)


def measure(workdir: Path, *, calls: int, size: int, channels: int, nodes: int, method: str, settle: float,
            payload: str = "garbage", budget: bool = True) -> dict:
    slots = grid_names(nodes)
    env = {} if budget else {BUDGET_OFF_ENV: "off"}
    rig = LocalRig(slots, workdir, output_size=(32, 32), content_size=(32, 32), mdns=False, env=env).create()
    try:
        rig.start_coordinator()
        rig.wait_ready()
        for s in slots:
            rig.start_node(s)
        pid = rig.coordinator.pid

        async def until_live():
            async with await rig.client() as c:
                await rig.wait_live(c, slots, timeout=120)

        asyncio.run(until_live())
        time.sleep(1.0)
        rss_before = _rss_kib(pid)
        log_before = rig.log("coordinator")
        sampler = _Sampler(pid)
        sampler.start()
        stop = threading.Event()
        times: list[float] = []
        result: dict = {}

        async def during():
            async with await rig.client() as c:      # logged in before the burst
                probe = asyncio.create_task(_status_probe(c, stop, times))
                t0 = time.monotonic()
                attack = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "bench.preauth_wire", rig.target, method, str(calls), str(size), str(channels), payload,
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
                async with asyncio.timeout(300):
                    out, err = await attack.communicate()
                result["burst_s"] = round(time.monotonic() - t0, 2)
                result["codes"] = json.loads(out) if attack.returncode == 0 else {"attack failed": err.decode()[-500:]}
                await asyncio.sleep(settle)
                stop.set()
                await probe
                st = await c.status()
                result["nodes_live_first_join"] = sum(1 for n in st.nodes if n.state == NodeState.LIVE and n.joins == 1)
                result["refusals_counted"] = sum(r.count for r in st.refusals)
                adm = getattr(st, "admission", None)        # the coordinator's own count, where it has one
                if adm is not None:
                    result["admission"] = dataclasses.asdict(adm)

        asyncio.run(during())
        sampler.stop.set()
        sampler.join()
        rss_after = _rss_kib(pid)
        log_lines = rig.log("coordinator")[len(log_before):].splitlines()
        return {
            "rss_before_mib": round(rss_before / 1024, 1),
            "rss_peak_mib": round(sampler.peak_kib / 1024, 1),
            "rss_after_mib": round(rss_after / 1024, 1),
            "rss_samples": sampler.samples,
            "status_max_s": round(max(times), 3) if times else None,
            "status_calls": len(times),
            "nodes": nodes,
            "log_lines": len(log_lines),
            "tracebacks": sum(1 for line in log_lines if line.startswith("Traceback")),
            **result,
        }
    finally:
        rig.close()


def run(args: argparse.Namespace) -> int:
    params = {"calls": args.calls, "size_mib": args.size_mib, "channels": args.channels, "nodes": args.nodes,
              "method": args.method, "settle_s": args.settle, "payload": args.payload}
    kw = dict(calls=args.calls, size=int(args.size_mib * MIB), channels=args.channels, nodes=args.nodes,
              method=args.method, settle=args.settle, payload=args.payload)
    with run_dir(args.keep, "preauth") as work:
        if args.compare:
            figures = {"without_budget": measure(work / "without", budget=False, **kw),
                       "with_budget": measure(work / "with", **kw)}
        else:
            figures = measure(work, **kw)
    print(json.dumps({"benchmark": "preauth", "figures": figures, "parameters": params, "machine": machine(),
                      "load": load()}, indent=2))
    return 0
