"""`shadowless bench NAME …`: reproducible benchmarks that print one JSON document.

Each benchmark is a module ``bench/<name>.py`` exposing ``configure(parser)``
and ``run(args) -> int``; it prints the figures, the machine and the parameters.
``--keep-json FILE`` (before or after NAME) also writes that document to FILE with the command,
date, machine and load, as docs/benchmarks/ keeps it (bench/keep.py).
"""
from __future__ import annotations

import argparse
import importlib
import signal

from bench import keep

BENCHMARKS: dict[str, str] = {
    "sync": "swap synchronisation of N real node processes on loopback",
    "swarm": "coordinator CPU per node and per frame under a swarm of protocol-level nodes (timeline, live)",
    "room": "virtual-room capture speed and light-drop statistics per projector subset",
    "calibration": "captures, time and error of sequential vs multiplexed calibration",
    "board": "the printed ChArUco board found on the room's table: table mapping error per sheet size, oblique view",
    "compensation": "blur-compensation solve time and quality, ours vs the per-projector baseline",
    "compensation_room": "blur compensation through the coordinator's jobs in the virtual room: captures, L error, quality",
    "compensation_cluster": "a video compensated on a local Dask cluster of 1 and 2 workers vs the same segments here",
    "compensation_bust": "blur compensation on the bust (a mesh rig, texture space) in the virtual room: captures, quality",
    "venue": "a rig on a virtual venue network (namespaces, rate-limited links): discovery and asset distribution",
    "node": "what a node costs its edge computer: render/upload time, CPU, memory, install size (GL 3.3+ and 3.1)",
    "discovery": "real nodes join their rig while a twin (same id, other token) and another rig advertise",
    "console": "the operator console in headless Chromium: page load, time to all live, update latency, CPU, thumbnails",
    "console_shots": "every console screenshot in docs/ from a running console: the layout over 25 overlapping "
                     "projectors, point picking, the cue panel and the whole page during a show in the virtual room",
    "console_login": "guessers on many loopback addresses vs the console's login limits: tries evaluated, operator's time in",
    "bust": "coverage on the bust from poses + mesh vs the room's truth; fingertip touches: shadow area vs coverage",
    "motion": "a hand waving over the table: light drop per frame, synthetic aperture vs reactive compensation with latency",
    "plan": "the layout planner: 25 of 100 ceiling positions (time), proxy curve and knee, the paper's guidelines, bust walls",
    "placement": "where the bust goes under the 5x5 ceiling rig: min coverage chosen vs default, search time, the coverage tool's check",
    "preauth": "unauthenticated calls under the size cap: coordinator memory (peak, after), status time, nodes live, log",
    "crash": "kill -9 of the coordinator during every write path: rigs that fail to start, writes lost, files left over",
    "uniformity": "per-pixel blending in the virtual room: flat-white uniformity before/after (table, wall seams, bust), "
                  "failover and lamp watchdog with real processes, blend captures, the node's cost",
    "show_control": "what people and show control cost: a login's password check (CPU), OSC status round trip, gain to applied, the MTC chase's error",
    "specular": "a glossy table seen by an observer: peak highlight and its area under P1, P9, P25 at matched light vs 1/N",
    "startup": "CPU a coordinator (with and without mDNS and the console) and a node spend from exec to serving "
               "and to joined, against another commit's taking turns",
    "image_bombs": "small files declaring 100-megapixel images, console decoder before/after: peak memory, time, outcome",
}


class _LazyBenchmarks(argparse._SubParsersAction):
    """The benchmarks' subparsers, each filled in by its module only when that benchmark is named: a
    benchmark's imports (SciPy, OpenCV, the room) cost only the run that needs them."""

    def __call__(self, parser, namespace, values, option_string=None):
        name = values[0] if values else None
        p = self._name_parser_map.get(name)
        if p is not None and not getattr(p, "_bench_configured", False):
            _configure_one(name, p)
        super().__call__(parser, namespace, values, option_string)


def _configure_one(name: str, p: argparse.ArgumentParser) -> None:
    p._bench_configured = True
    try:
        mod = importlib.import_module(f"bench.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"bench.{name}":
            raise
        p.set_defaults(_bench=None)
        return
    mod.configure(p)
    keep.add_options(p, after_name=True)
    p.set_defaults(_bench=mod)


EPILOG = """\
keep a run's JSON for the docs (the command, date, machine and load around it):
  shadowless bench --keep-json docs/benchmarks/crash.json --note "quiet machine" crash --trials 200
"""


def configure(parser: argparse.ArgumentParser) -> None:
    keep.add_options(parser)
    if parser.epilog is None:
        parser.epilog = EPILOG
    sub = parser.add_subparsers(dest="bench", metavar="NAME", required=True, action=_LazyBenchmarks)
    for name, summary in BENCHMARKS.items():
        sub.add_parser(name, help=summary, description=summary)


def unwind_on_signals() -> None:
    """SIGTERM and SIGHUP (a timeout, a closed terminal, a service stop) end a benchmark as Ctrl-C does:
    by an exception that unwinds it (SystemExit 128 + the signal), so its ``with`` and ``finally``
    blocks run: its temporary directories (hundreds of MB for the room's captures) are removed and the
    processes it started are stopped. Only over the default handler; a second signal kills at once."""
    def unwind(signum, frame):
        signal.signal(signum, signal.SIG_DFL)
        raise SystemExit(128 + signum)

    for sig in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) == signal.SIG_DFL:
            signal.signal(sig, unwind)


def run(args: argparse.Namespace) -> int:
    unwind_on_signals()
    if args._bench is None:
        raise SystemExit(f"benchmark {args.bench!r} is not available in this build")
    if getattr(args, "keep_json", None):
        return keep.run_kept(args, args._bench.run)
    if getattr(args, "keep_note", None):
        raise SystemExit("--note goes with --keep-json FILE: it is kept as the JSON's source")
    return int(args._bench.run(args) or 0)
