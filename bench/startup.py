"""`shadowless bench startup`: the CPU a coordinator and a node spend starting.

Every process of the rig pays its start-up before it serves anything: a coordinator restarted during a
show takes that CPU from the nodes that share its host, and the test suite starts hundreds of them. The
bench starts, on a temporary 2x2 rig and loopback only:

* ``coordinator``: ``python -m shadowless coordinator --no-mdns --no-console`` (how tests and the venue
  bench start one) from exec until its port file is written, i.e. it listens;
* ``coordinator_full``: the same with mDNS (on 127.0.0.1) and the console, as an operator runs it;
* ``node``: ``python -m shadowless node --coordinator … --output offscreen`` until it logs that it joined
  the rig, its presenter process included.

The CPU is the process tree's user + system time from /proc at that moment (so an idle spin after the
work counts only up to it). Bytecode is cached in a directory of the run (as an installed rig has it),
and each kind is started once first to write it. ``--against COMMIT`` extracts that commit's tree with
``git archive`` and starts the same programs from it, the two trees taking turns start by start, so both
see the same load; the JSON gives medians and every start's figure.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.workdir import run_dir
from coordinator.rig import init_rig
from protos.cli_types import int_range, names

REPO = Path(__file__).resolve().parents[1]
_TICK = os.sysconf("SC_CLK_TCK")
KINDS = ("coordinator", "coordinator_full", "node")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = """\
examples:
  shadowless bench startup                      # 10 starts of each kind, this tree
  shadowless bench startup --starts 20 --against HEAD~3
  shadowless bench startup --kinds coordinator --starts 5
"""
    parser.add_argument("--starts", type=int_range(1), default=10, metavar="N", help="starts of each kind (default 10)")
    parser.add_argument("--kinds", type=names, default=list(KINDS), metavar="K,…",
                        help=f"which starts to measure, of {', '.join(KINDS)} (default: all)")
    parser.add_argument("--against", metavar="COMMIT", help="also start that commit's programs, taking turns")
    parser.add_argument("--keep", metavar="DIR", help="keep the rig, bytecode and logs in DIR/startup")


def _cpu_s(pid: int) -> float:
    """User + system seconds of ``pid`` and every descendant alive now."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / _TICK
            for task in os.listdir(f"/proc/{p}/task"):
                todo += [int(c) for c in Path(f"/proc/{p}/task/{task}/children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError):
            pass
    return total


def _stop(p: subprocess.Popen) -> None:
    from shadowless.process_stop import stop_process

    stop_process(p, timeout=30.0)


class _Starter:
    """Starts one tree's programs on the run's rig, with bytecode cached in the run."""

    def __init__(self, tree: Path, work: Path, env: dict[str, str]):
        self.tree, self.work, self.env = tree, work, env

    def _popen(self, args: list[str], **kw) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "shadowless", *args], cwd=self.tree, env=self.env,
                                stdin=subprocess.DEVNULL, **kw)

    def coordinator(self, *, full: bool = False, keep: bool = False,
                    rig: str = "rig") -> tuple[float, subprocess.Popen | None, int]:
        port_file = self.work / f"port.{os.getpid()}.{time.monotonic_ns()}"
        args = ["coordinator", "--rig", str(self.work / rig), "--listen", "127.0.0.1:0", "--port-file", str(port_file)]
        args += ["--mdns-interface", "127.0.0.1", "--console", "127.0.0.1:0"] if full else ["--no-mdns", "--no-console"]
        log = open(self.work / "coordinator.log", "ab")
        p = self._popen(args, stdout=log, stderr=log)
        log.close()
        deadline = time.monotonic() + 120
        try:
            while not port_file.exists() or not port_file.read_text().strip():
                if p.poll() is not None:
                    raise SystemExit(f"bench startup: the coordinator of {self.tree} ended ({p.returncode}); "
                                     f"see {self.work / 'coordinator.log'}")
                if time.monotonic() > deadline:
                    raise SystemExit("bench startup: no coordinator listening after 120 s")
                time.sleep(0.005)
            cpu, port = _cpu_s(p.pid), int(port_file.read_text())
        except BaseException:
            _stop(p)
            raise
        finally:
            port_file.unlink(missing_ok=True)
        if keep:
            return cpu, p, port
        _stop(p)
        return cpu, None, port

    def node(self, port: int) -> float:
        args = ["node", "--slot", "r0c0", "--coordinator", f"127.0.0.1:{port}", "--token-file",
                str(self.work / "node_rig" / "token"), "--output", "offscreen", "--cache-dir", str(self.work / "cache")]
        p = self._popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120
            for line in p.stderr:
                if "joined rig" in line:
                    return _cpu_s(p.pid)
                if time.monotonic() > deadline:
                    break
            raise SystemExit(f"bench startup: the node of {self.tree} did not join ({p.poll()})")
        finally:
            _stop(p)
            p.stderr.close()


def _extract(commit: str, into: Path) -> None:
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)


def _summary(values: list[float]) -> dict:
    return {"median_cpu_s": round(statistics.median(values), 3), "min_cpu_s": round(min(values), 3),
            "starts_cpu_s": [round(v, 3) for v in values]}


def run(args: argparse.Namespace) -> int:
    kinds = args.kinds
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise SystemExit(f"--kinds: {', '.join(unknown)} is not one of {', '.join(KINDS)}")
    with run_dir(args.keep, "startup") as work:
        # as from an operator's shell: without what this process's own `shadowless` set for itself (the
        # BLAS threads' spin, shadowless/cli.py), which each tree's programs set, or not, themselves
        from shadowless.cli import BLAS_ENV

        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE" and k not in BLAS_ENV}
        env["PYTHONPYCACHEPREFIX"] = str(work / "pycache")      # bytecode cached, as an installed rig has it
        env["LP_NUM_THREADS"] = "1"                              # the presenter's llvmpipe: one thread
        for rig in ("rig", "node_rig"):     # one rig serves one coordinator: the nodes' stays up for the run
            init_rig(work / rig, name=f"startup-{rig}".replace("_", "-"), slots=["r0c0", "r0c1", "r1c0", "r1c1"],
                     width=64, height=48, content_width=64, content_height=48, force=True)
        trees = {"now": REPO}
        old = None
        if args.against:
            old = Path(tempfile.mkdtemp(prefix="shadowless-startup-"))
            _extract(args.against, old)
            trees["before"] = old
        try:
            starters = {name: _Starter(tree, work, env) for name, tree in trees.items()}
            figures: dict[str, dict[str, list[float]]] = {k: {name: [] for name in trees} for k in kinds}
            # the node's coordinator: this tree's, kept for the run
            coord, port = None, 0
            if "node" in kinds:
                _, coord, port = starters["now"].coordinator(keep=True, rig="node_rig")
            try:
                for k in range(args.starts + 1):        # start 0 writes the bytecode and is not counted
                    print(f"bench startup: round {k}/{args.starts}", file=sys.stderr, flush=True)
                    for name, st in starters.items():
                        for kind in kinds:
                            if kind == "node":
                                cpu = st.node(port)
                            else:
                                cpu = st.coordinator(full=kind == "coordinator_full")[0]
                            if k:
                                figures[kind][name].append(cpu)
            finally:
                if coord is not None:
                    _stop(coord)
        finally:
            if old is not None:
                subprocess.run(["rm", "-rf", str(old)], check=False)
    out: dict = {"benchmark": "startup", "starts": args.starts, "against": args.against,
                 "load": os.getloadavg()}
    for kind in kinds:
        out[kind] = {name: _summary(v) for name, v in figures[kind].items()}
        if "before" in trees:
            out[kind]["ratio"] = round(out[kind]["now"]["median_cpu_s"] / out[kind]["before"]["median_cpu_s"], 3)
    print(json.dumps(out, indent=1))
    return 0
