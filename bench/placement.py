"""`shadowless bench placement`: where the bust goes under the 5x5 ceiling rig, and whether the
coverage tool agrees.

Runs `shadowless plan --placement` (:func:`shadowless.placement.place`) with its defaults (a
search budget of ``--seconds``, then the check of the best few and the default at the coverage
tool's settings), then builds a rig directory from the written layout (`rig init --layout`, the
check resolution) and runs the coverage tool on it (`coverage --planned`). Prints
``placement.min_coverage_chosen`` and ``placement.min_coverage_default`` (the fewest projectors
reaching a lit texel of the bust), ``placement.seconds`` (the whole command, wall clock; and its
CPU time: on a shared machine the two differ), and what the coverage tool reported for the written
placement (``placement.coverage_tool``), which must equal the search's own figures.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from bench.machine import machine
from coordinator.coverage_run import compute_coverage
from coordinator.rig import Rig
from coordinator.rig_layout import init_from_layout
from shadowless import placement
from shadowless.rig import builtin_mesh


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=40.0, help="the search's time budget (default 40)")
    parser.add_argument("--out", metavar="DIR", help="keep the layout and the picture here (default: a temporary directory)")


def run(args: argparse.Namespace) -> int:
    p = argparse.ArgumentParser()
    placement.configure(p)
    with tempfile.TemporaryDirectory(prefix="bench-placement-") as tmp:
        out = Path(args.out or tmp)
        out.mkdir(parents=True, exist_ok=True)
        opts = p.parse_args(["--placement", "--seconds", str(args.seconds), "--layout", str(out / "placement.toml"),
                             "--picture", str(out / "placement.png")])
        doc = placement.place(opts, say=lambda text: print(f"placement: {text}", file=sys.stderr, flush=True))
        rig_dir = Path(tmp) / "rig"
        init_from_layout(rig_dir, out / "placement.toml", builtin_mesh=builtin_mesh, resolution=tuple(opts.check_resolution))
        tool = compute_coverage(Rig(rig_dir), planned=True, texture=tuple(opts.texture), shadow_scale=opts.shadow_scale,
                                views=[("orbit", (0.0, 90.0))], panel=(96, 96), out=Path(tmp) / "coverage.png")
    c = doc["chosen"]
    figures = {
        "min_coverage_chosen": doc["min_coverage_chosen"], "min_coverage_default": doc["min_coverage_default"],
        "seconds": doc["seconds"], "cpu_seconds": doc["cpu_seconds"], "search_seconds": doc["search_seconds"],
        "evaluated": doc["evaluated"], "stopped_early": doc["stopped_early"],
        "chosen": c, "default": doc["default"],
        "coverage_tool": {"count_min": tool["count_min"], "count_p5": tool["count_p5"], "lit_pct": tool["lit_pct"],
                          "count_mean": tool["count_mean"]},
        "coverage_tool_agrees": tool["count_min"] == c["count_min"] and tool["count_p5"] == c["count_p5"]
                                and abs(tool["lit_pct"] - (100.0 - c["unlit_pct"])) < 0.05,
        "chosen_at_least_default": doc["min_coverage_chosen"] >= doc["min_coverage_default"],
    }
    print(json.dumps({"placement": figures, "search": doc["search"], "check": doc["check"], "tilt": doc["tilt"],
                      "layout": doc["layout"] if args.out else None, "picture": doc["picture"] if args.out else None,
                      "machine": machine()}, indent=2))
    return 0
