"""`shadowless study motion`: a hand moving over the table, the synthetic aperture against a reactive system.

:func:`add_motion_arguments` and :func:`run_study` are shared with ``shadowless
bench motion``, which prints the same figures as one JSON document.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from protos import cli_types
from sim.motion import (
    DEFAULT_FPS,
    DEFAULT_SUBSETS,
    GESTURES,
    MotionResult,
    gesture,
    run_motion,
)
from sim.reactive import DEFAULT_CAP, PRIOR_RIGS, ReactiveSpec, rig_slots
from sim.room import Room
from sim.scene import SUBSETS, reference_scene

__all__ = ["add_motion_arguments", "configure", "reactive_specs", "run", "run_study"]

EPILOG = """\
what it computes, per frame (from the room's ground truth, not captures):
  passive rigs   P1 (one bright projector), P9D ... P25 (the paper's subsets), P2 (two projectors
                 1 m apart, the size of prior reactive rigs): every projector at its nominal drive,
                 nothing computed, so the soft shadow is wherever the hand is
  reactive       the same projectors re-solved for the hand as seen LATENCY ago: the unblocked ones
                 boosted (at most CAP times) to restore each point; `suppress` also switches off the
                 blocked ones where they hit the hand. The shadow lags the hand; ghosts where it was
figures: largest drop, area with >= 10/50/90 % drop (90 %: the umbra), light lost; reactive systems
also the over-bright area (>= 10 % too bright); each integrated over time (mm^2 s: a frame lasts 1/fps)

writes into --out: motion.json (figures per frame and integrated), motion.png (drop over time),
motion.mp4 (the chosen systems side by side, with the hand's outline and a time stamp)

examples:
  shadowless study motion                                  # 5 s of waving 0.2 m above the table
  shadowless study motion --gesture touch --duration 2.4 --out touch
  shadowless study motion --latency 50,100 --reactive-rig P25 --rule boost --json
  shadowless study motion --show P1,P9D,P25,reactive_50ms --latency 50
"""

_RULES = ("boost", "suppress")

#: The movie's panels unless --show says otherwise (those of them the run has): one bright projector,
#: the synthetic aperture, the issue's reactive system, and the one that leaves a lagging umbra.
DEFAULT_SHOW = ("P1", "P25", "reactive_100ms", "reactive_100ms_P2_suppress")


def _latencies(text: str) -> list[float]:
    """``"0,50,100"`` -> [0.0, 50.0, 100.0]: latencies in ms, each 0..2000."""
    one = cli_types.number(0, 2000)
    try:
        out = [one(v) for v in str(text).split(",") if v.strip()]
    except argparse.ArgumentTypeError:
        out = []
    if not out:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list of latencies: milliseconds 0..2000 joined by commas, e.g. 50,100")
    return out


def _rigs(text: str) -> list[str]:
    out = cli_types.names(text)
    for name in out:
        try:
            rig_slots(name)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return out


def _rules(text: str) -> list[str]:
    out = cli_types.names(text)
    bad = [r for r in out if r not in _RULES]
    if bad:
        raise argparse.ArgumentTypeError(f"{text!r}: rules are boost (boost the unblocked projectors) and suppress (also switch off the blocked ones)")
    return out


def add_motion_arguments(p: argparse.ArgumentParser, *, latency: str = "100") -> None:
    """The options of the study (and of ``bench motion``): the gesture, the frame rate, the systems, the room."""
    g = p.add_argument_group("the hand")
    g.add_argument("--gesture", choices=list(GESTURES), default="wave",
                   help="; ".join(f"{k}: {d}" for k, (_, d) in GESTURES.items()) + " (default wave)")
    g.add_argument("--height", type=cli_types.number(0, 1000), default=200.0, metavar="MM", help="height of the hand's lowest point for wave and reach (default 200)")
    g.add_argument("--duration", type=cli_types.number(0, 600, lo_open=True), default=5.0, metavar="S", help="seconds of motion (default 5)")
    g.add_argument("--fps", type=cli_types.number(1, 1000), default=DEFAULT_FPS, metavar="HZ",
                   help=f"frames per second: the projectors' refresh, at which the hand is sampled (default {DEFAULT_FPS:g})")
    s = p.add_argument_group("the systems")
    s.add_argument("--subsets", type=_rigs, default=list(DEFAULT_SUBSETS), metavar="P1,P25,...",
                   help=f"passive rigs (default all: {','.join(DEFAULT_SUBSETS)})")
    s.add_argument("--latency", type=_latencies, default=_latencies(latency), metavar="MS[,MS...]",
                   help=f"end-to-end latencies of the reactive systems, ms, in whole frames (default {latency})")
    s.add_argument("--reactive-rig", type=_rigs, default=["P25", *PRIOR_RIGS], metavar="P25,P2",
                   help="projectors the reactive systems drive (default P25,P2)")
    s.add_argument("--rule", type=_rules, default=list(_RULES), metavar="boost,suppress",
                   help="compensation rules: boost the unblocked projectors; suppress: also switch off the blocked ones on the hand (default both)")
    s.add_argument("--cap", type=cli_types.number(1, 100), default=DEFAULT_CAP, metavar="X",
                   help=f"largest boost of a projector over its nominal drive, its headroom (default {DEFAULT_CAP:g}: nominal is half the maximum)")
    r = p.add_argument_group("the room")
    r.add_argument("--camera-scale", type=cli_types.number(0, 1, lo_open=True), default=0.25, metavar="S",
                   help="camera resolution relative to 2592x1944 (default 0.25: ~2 mm of table per pixel)")
    r.add_argument("--seed", type=int, default=0, help="unit-to-unit variation of the rig (default 0)")


def reactive_specs(args: argparse.Namespace) -> list[ReactiveSpec]:
    """One :class:`ReactiveSpec` per rig, latency and rule of ``args`` (duplicates in whole frames dropped)."""
    out: dict[str, ReactiveSpec] = {}
    for rig in args.reactive_rig:
        for ms in args.latency:
            for rule in args.rule:
                spec = ReactiveSpec(latency_s=ms / 1000.0, subset=rig, cap=args.cap, suppress=rule == "suppress")
                out.setdefault(spec.name(args.fps), spec)
    return list(out.values())


def _label(name: str, specs: dict[str, ReactiveSpec], fps: float) -> str:
    """The line under a movie panel's name: what the system is."""
    spec = specs.get(name)
    if spec is None:
        n = len(rig_slots(name))
        return "1 bright projector, nothing computed" if name == "P1" else f"{n} projectors, nothing computed"
    ms = 1000.0 * spec.latency_frames(fps) / fps
    return f"{len(rig_slots(spec.subset))} projectors re-solved {ms:.0f} ms late ({'boost + suppress' if spec.suppress else 'boost'})"


def run_study(args: argparse.Namespace, *, out: Path | None, show: list[str] | None = None, progress: bool = True) -> tuple[dict, MotionResult]:
    """Run the study ``args`` describe; with ``out``, write motion.json, motion.png and (``show``) motion.mp4 there.

    ``show``: the movie's systems, left to right; ``["default"]``: those of :data:`DEFAULT_SHOW` in the run.

    Returns the document (parameters, per-system summary, files; no per-frame series) and the result.
    """
    specs = reactive_specs(args)
    by_name = {s.name(args.fps): s for s in specs}
    names = [*args.subsets, *by_name]
    if show == ["default"]:
        show = [n for n in DEFAULT_SHOW if n in names]
    if show:
        unknown = [n for n in show if n not in names]
        if unknown:
            raise SystemExit(f"--show: no system {', '.join(unknown)} in this run; systems are {', '.join(names)}")
    t0 = time.perf_counter()
    room = Room(reference_scene(projector_scale=0.25, camera_scale=args.camera_scale, seed=args.seed), seed=args.seed, noise=False)
    room.prepare()
    prepare_s = time.perf_counter() - t0
    path = gesture(args.gesture, height=args.height)
    movie = None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    if out is not None and show:
        from sim.motion_media import MotionMovie

        view_shape = room.view().shape
        movie = MotionMovie(out / "motion.mp4", [(n, _label(n, by_name, args.fps)) for n in show], fps=args.fps, shape=view_shape,
                            note=f"{args.gesture} at {args.fps:g} fps")
    t1 = time.perf_counter()
    try:
        result = run_motion(room, path, duration=args.duration, fps=args.fps, subsets=args.subsets, reactive=specs,
                            on_frame=movie.add if movie is not None else None, progress=progress)
    finally:
        if movie is not None:
            movie.close()
    compute_s = time.perf_counter() - t1
    params = {
        "gesture": args.gesture, "height_mm": args.height, "duration_s": args.duration, "fps": args.fps,
        "frames": len(result.times), "latency_ms": args.latency, "reactive_rigs": args.reactive_rig, "rules": args.rule,
        "cap": args.cap, "camera": list(room.camera_size()), "seed": args.seed,
        "prior_rigs": {n: rig_slots(n) for n in sorted({*args.subsets, *args.reactive_rig}) if n not in SUBSETS},
        "table_mm2_seen": round(result.table_mm2, 1),
    }
    doc = {"study": "motion", "parameters": params, "systems": result.summary(),
           "seconds": {"prepare": round(prepare_s, 2), "frames": round(compute_s, 2), "per_frame": round(compute_s / len(result.times), 4)}}
    if out is not None:
        files = {"json": str(out / "motion.json"), "plot": str(out / "motion.png")}
        if movie is not None:
            files["movie"] = str(out / "motion.mp4")
        doc["files"] = files
        from sim.motion_media import plot_png

        plotted = [n for n in result.frames if n in ("P1", "P25", *PRIOR_RIGS) or n in result.reactive]
        plot_png(result, out / "motion.png", systems=plotted,
                 title=f"{args.gesture}: light drop per frame at {args.fps:g} fps (passive rigs vs reactive compensation)")
        full = dict(doc)
        full["per_frame"] = {"times_s": [round(float(t), 5) for t in result.times],
                             "systems": {n: {k: [round(float(v), 4) for v in s] for k, s in f.items()} for n, f in result.frames.items()}}
        (out / "motion.json").write_text(json.dumps(full, indent=1))
    return doc, result


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "A hand moving over the table in the virtual room, frame by frame: the light each passive rig\n"
        "loses under it (the synthetic aperture computes nothing, so its soft shadow follows the hand at\n"
        "once) against a reactive system that re-solves for where the hand was one latency ago.")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    add_motion_arguments(p)
    o = p.add_argument_group("output")
    o.add_argument("--out", type=Path, default=Path("motion"), metavar="DIR", help="folder for motion.json, motion.png, motion.mp4 (default ./motion)")
    o.add_argument("--show", type=cli_types.names, default=["default"], metavar="A,B,C",
                   help=f"systems side by side in the movie, left to right (default: those of {','.join(DEFAULT_SHOW)} in the run)")
    o.add_argument("--no-movie", action="store_true", help="skip the movie (faster)")
    o.add_argument("--json", action="store_true", help="print the JSON document (without the per-frame series) instead of the table")


def _table(doc: dict) -> str:
    head = f"{'system':<28}{'proj':>5}{'max drop':>10}{'>=50% cm2 s':>13}{'umbra cm2 s':>13}{'umbra s':>9}{'ghost cm2 s':>13}{'max over':>10}"
    rows = [head]
    for name, s in doc["systems"].items():
        ghost = s.get("integrated_area_overbright_above_10_mm2_s")
        over = s.get("max_overbright")
        rows.append(
            f"{name:<28}{s['projectors']:>5}{100 * s['max_drop']:>9.0f}%{s['integrated_area_above_50_mm2_s'] / 100:>13.1f}"
            f"{s['integrated_area_above_90_mm2_s'] / 100:>13.1f}{s['umbra_visible_s']:>9.2f}"
            f"{'' if ghost is None else f'{ghost / 100:.1f}':>13}{'' if over is None else f'{100 * over:.0f}%':>10}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    show = None if args.no_movie else args.show
    doc, _ = run_study(args, out=args.out, show=show, progress=True)
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    p = doc["parameters"]
    print(f"{p['gesture']} for {p['duration_s']:g} s at {p['fps']:g} fps ({p['frames']} frames), camera {p['camera'][0]}x{p['camera'][1]}")
    print(_table(doc))
    print("cm2 s: area x time, summed over frames of 1/fps s; umbra: >= 90 % drop; ghost: >= 10 % over-bright")
    for k, v in doc.get("files", {}).items():
        print(f"{k}: {v}")
    return 0
