"""`shadowless bench show_control`: what people and show control cost the coordinator.

* **login**: the CPU time of one password check (a scrypt hash at the store's parameters), which
  every login by name costs, in a worker thread beside the event loop; and its wall time here.
* **OSC**: a coordinator (no nodes) listening for OSC on loopback; a client sends
  ``/shadowless/status`` and waits for the six status messages (the round trip), then
  ``/shadowless/gain * VALUE`` and waits until every slot holds the value (command to applied).
  The load averages say how busy the machine was.
* **MTC**: the MIDI timecode chase (:mod:`bench.show_control_mtc`): a show chasing MTC sent in
  real time, its error against the MTC clock once settled, and no seek once MTC stops.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import socket
import statistics
import time

from bench import show_control_mtc
from bench.machine import load, machine
from bench.workdir import run_dir
from protos.cli_types import int_range, number


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rounds", type=int_range(10, 100000), default=200,
                   help="OSC round trips and gain commands timed (default 200)")
    p.add_argument("--logins", type=int_range(1, 1000), default=20, help="password checks timed (default 20)")
    p.add_argument("--slots", type=int_range(1, 256), default=25, help="slots of the rig (default 25)")
    p.add_argument("--mtc-seconds", type=number(2.0, 600.0), default=8.0,
                   help="seconds of MIDI timecode sent to a playing show (default 8)")
    p.add_argument("--keep", metavar="DIR", help="keep the rig directory here")


def _pct(values: list[float], p: float) -> float:
    s = sorted(values)
    return round(s[min(len(s) - 1, int(p / 100 * len(s)))], 3)


def _logins(n: int) -> dict:
    from coordinator import users

    stored = users.hash_password("a password of twenty")
    cpu, wall = [], []
    for _ in range(n):
        c0, w0 = time.process_time(), time.perf_counter()
        assert users.password_matches("a password of twenty", stored)
        cpu.append((time.process_time() - c0) * 1e3)
        wall.append((time.perf_counter() - w0) * 1e3)
    return {"scrypt": {"n": users.SCRYPT_N, "r": users.SCRYPT_R, "p": users.SCRYPT_P},
            "check_cpu_ms_median": round(statistics.median(cpu), 1), "check_wall_ms_median": round(statistics.median(wall), 1),
            "checks": n}


async def _osc(args: argparse.Namespace, workdir) -> dict:
    from coordinator.app import CoordinatorApp
    from coordinator.osc.service import encode
    from coordinator.rig import Rig, grid_slots, init_rig

    rig_dir = init_rig(workdir / "rig", name="show-control", slots=grid_slots(1, args.slots), width=32, height=32,
                       content_width=64, content_height=32, force=True)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\n')
    app = CoordinatorApp(Rig(rig_dir), b"s" * 32, listen="127.0.0.1:0", advertise=False)
    await app.start()
    loop = asyncio.get_running_loop()
    target = ("127.0.0.1", app.osc.port)
    rtt, applied = [], []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        try:
            for _ in range(args.rounds):
                t0 = time.perf_counter()
                s.sendto(encode("/shadowless/status", ()), target)
                for _ in range(6):
                    await loop.sock_recv(s, 65536)
                rtt.append((time.perf_counter() - t0) * 1e3)
            slots = app.coordinator.rig.slots
            for i in range(args.rounds):
                value = 0.5 + (i % 2) * 0.25
                t0 = time.perf_counter()
                s.sendto(encode("/shadowless/gain", ("*", value)), target)
                while any(st.gain != value for st in slots.values()):
                    await asyncio.sleep(0)
                applied.append((time.perf_counter() - t0) * 1e3)
        finally:
            await app.stop()
    return {"status_round_trip_ms_p50": _pct(rtt, 50), "status_round_trip_ms_p99": _pct(rtt, 99),
            "gain_all_slots_applied_ms_p50": _pct(applied, 50), "gain_all_slots_applied_ms_p99": _pct(applied, 99),
            "rounds": args.rounds, "slots": args.slots, "nodes": 0}


def run(args: argparse.Namespace) -> int:
    figures = {"login": _logins(args.logins)}
    with run_dir(args.keep, "show-control") as d:
        figures["osc"] = asyncio.run(_osc(args, d))
        figures["mtc"] = asyncio.run(show_control_mtc.measure(d, args.mtc_seconds))
    doc = {"benchmark": "show_control", "machine": machine(), "load": load(), "figures": figures,
           "parameters": {"rounds": args.rounds, "logins": args.logins, "slots": args.slots,
                          "mtc_seconds": args.mtc_seconds}}
    print(json.dumps(doc, indent=2))
    return 0
