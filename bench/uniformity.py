"""`shadowless bench uniformity`: how even the rig's light is before and after the per-pixel blend,
through failover and a dimmed lamp, and what the blend costs a node. One JSON document.

Parts (``--only`` picks some; each prints progress lines on stderr):

* ``table`` -- the 5x5 table rig with a brightness and white-point spread, a hot spot and
  vignetting on top of the lens's fall-off: flat-white non-uniformity over the covered area
  (p99 of ``|I / (k target) - 1|`` on 8x8 block means, captured) before and after the blend, and
  the per-channel deviation of a flat grey (:mod:`bench.uniformity_measure`);
* ``wall`` -- three projectors side by side overlapping by 20 %: the largest luminance step
  across a seam (where the number of projectors reaching the surface changes), before and after;
* ``bust`` -- the bust with projectors around it: non-uniformity over the bust's surface that
  three or more projectors reach, before and after;
* ``captures`` -- the blend job's captures for 1 projector and for 25 (planar);
* ``failover`` -- real coordinator and node processes in the room on P25 and P9: a node killed
  during a flat-white show (a still on rigs of more than 9 nodes, ``--show``), the time until the coordinator declares it lost, the non-uniformity in its
  footprint once the remaining nodes show their new maps, and how many frames after the
  declaration those maps were on screen (the nodes' heartbeats: the pts of the first frame
  shown with them); then the node returns and the maps switch back, and the same node is lost
  once more (``again``: the switch lead the coordinator learned from the switches before, which
  a rig's first failover after its coordinator starts does not have);
* ``watchdog`` -- the same rig (P25) showing a flat-white still, with one lamp dimmed to 50 % and one to 0 through the room's
  lamp switch while the nodes stay live: the time until the watchdog names each, its gain
  estimate against the room's truth, and the non-uniformity once re-blended;
* ``node`` -- ``bench node``'s figures of a 1080p blend: render time ratio and resident memory.

The in-process parts run the coordinator's jobs against the room through the in-process rig
(:mod:`bench.uniformity_room`); failover and watchdog run real processes
(:mod:`bench.uniformity_live`). Times are ratios or differences within one run. A part this build
cannot run reports ``null`` figures and a note under ``missing`` naming what is absent; it never
reports a number it did not measure.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from bench.machine import machine
from bench.uniformity_measure import channel_deviation, nonuniformity, seam_steps
from bench.uniformity_scenes import Light, Missing, bust_walls_room, slots_of, table_room, wall_room

PARTS = ("table", "wall", "bust", "captures", "failover", "watchdog", "node")

#: the issue's figures: key -> (part, target, how the target reads)
FIGURES: dict[str, tuple[str, float | None, str]] = {
    "table.before": ("table", None, "reported"),
    "table.after": ("table", 0.02, "<="),
    "table.colour_after": ("table", 0.02, "<="),
    "wall.seam_before": ("wall", None, "reported"),
    "wall.seam_after": ("wall", 0.01, "<="),
    "bust.before": ("bust", None, "reported"),
    "bust.after": ("bust", 0.03, "<="),
    "failover.P25.after": ("failover", 0.02, "<="),
    "failover.P25.frames_after_declared": ("failover", 3, "<="),
    "failover.P9.after": ("failover", 0.02, "<="),
    "failover.P9.frames_after_declared": ("failover", 3, "<="),
    "failover.P25.frames_after_declared_again": ("failover", 3, "<="),
    "failover.P9.frames_after_declared_again": ("failover", 3, "<="),
    "watchdog.detect_s": ("watchdog", 2.0, "<="),
    "watchdog.gain_error": ("watchdog", 0.05, "<="),
    "captures.1": ("captures", None, "reported"),
    "captures.25": ("captures", None, "reported"),
    "node.render_ratio": ("node", 1.05, "<="),
    "node.rss_delta_mb": ("node", 10.0, "<="),
}


def _log(msg: str) -> None:
    print(f"[bench uniformity] {msg}", file=sys.stderr, flush=True)


def _parts(text: str) -> list[str]:
    names = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in names if p not in PARTS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"parts are {', '.join(PARTS)}; got {text!r}")
    return names


def _budget(text: str) -> str | float:
    if text == "auto":
        return text
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not 0.0 < v <= 64:
        raise argparse.ArgumentTypeError(f"a CPU budget is a fraction of a core (e.g. 0.06) or auto, got {text!r}")
    return v


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n")[0].replace("`shadowless bench uniformity`: ", "")
    parser.epilog = ("examples:\n"
                     "  shadowless bench uniformity --quick                  # a small rig, every part (minutes)\n"
                     "  shadowless bench uniformity --only table,wall        # the in-process parts alone\n"
                     "  shadowless bench uniformity --only failover --failover-rigs P9\n"
                     "  shadowless bench uniformity --only bust --diagnose out/   # the mesh blend's model against the room\n"
                     "  shadowless bench uniformity                          # the full run (long)")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--quick", action="store_true",
                        help="small rigs at low resolution, true poses and LUTs, failover on P9 only, a short "
                             "`bench node`: a smoke run")
    parser.add_argument("--only", type=_parts, default=None, metavar="PART[,PART]",
                        help=f"run only these parts ({', '.join(PARTS)}; default all)")
    parser.add_argument("--projector-scale", type=float, default=None,
                        help="room projector resolution (default 0.25, 0.12 with --quick)")
    parser.add_argument("--camera-scale", type=float, default=None,
                        help="room camera resolution (default 0.25, 0.15 with --quick)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--brightness-spread", type=float, default=0.15, help="per-projector brightness, +- (0.15)")
    parser.add_argument("--white-spread", type=float, default=0.15, help="per-channel white point, +- (0.15)")
    parser.add_argument("--hotspot", type=float, default=0.15, help="extra light at each image centre (0.15)")
    parser.add_argument("--vignetting", type=float, default=0.2, help="light lost at each image's corners (0.2)")
    parser.add_argument("--poses", choices=("truth", "calibrate"), default=None,
                        help="planar rigs: the room's true poses or the calibrate job (default calibrate; truth "
                             "with --quick)")
    parser.add_argument("--luts", choices=("truth", "response"), default=None,
                        help="LUTs from the true gammas or the response job (default response; truth with --quick)")
    parser.add_argument("--headroom", type=float, default=None,
                        help="the blend's headroom 0..0.9 (default: the job's, enough for losing any one projector)")
    parser.add_argument("--map-scale", type=int, default=None, help="the blend maps' downscale (default: the job's)")
    parser.add_argument("--frames", type=int, default=None, help="captures averaged per figure (default 4, 2 with --quick)")
    parser.add_argument("--table-slots", default=None,
                        help="the table rig: P25, P9W, P9D, ... or N for the first N of the 5x5 (default P25; 4 with "
                             "--quick)")
    parser.add_argument("--failover-rigs", default=None,
                        help="rigs of the failover part, comma-separated (default P25,P9W; P9W with --quick)")
    parser.add_argument("--fps", type=float, default=30.0, help="the show's frame rate in the live parts (default 30)")
    parser.add_argument("--show", choices=("auto", "timeline", "still"), default="auto",
                        help="what the failover part shows: a looping flat-white timeline show at --fps, or a still "
                             "(then a frame is a period of --fps); auto (default): the show for rigs of up to 9 "
                             "nodes, the still for more (25 nodes each rendering and sending 30 frames a second to "
                             "the room are more than two cores carry: the coordinator starves and loses them)")
    parser.add_argument("--switch-lead-ms", type=float, default=None,
                        help="failover: rig.toml's [blend] switch_lead_ms, how far ahead the new maps are set "
                             "(default: the rig's); 1 shows what pushing and uploading the maps take")
    parser.add_argument("--cpu-budget", type=_budget, default=None, metavar="FRACTION|auto",
                        help="failover: run each rig again with each node process held to FRACTION of a core, "
                             "reserved, its rasterizer's threads (the GPU's stand-in) apart without a limit (a "
                             "cgroup per node; needs root), e.g. 0.06 for P25 on 2 cores; auto: "
                             "three quarters of the machine shared by the rig's nodes (0.06 for P25, 0.17 for P9 "
                             "on 2 cores)")
    parser.add_argument("--cpu-period-ms", type=float, default=20.0,
                        help="the budget's CFS period (default 20 ms: a node out of quota waits at most that long)")
    parser.add_argument("--node-frames", type=int, default=None, help="frames per profile of `bench node` (default 120; "
                                                                      "20 with --quick)")
    parser.add_argument("--keep", metavar="DIR", help="keep rig directories and logs here")
    parser.add_argument("--diagnose", metavar="DIR", default=None,
                        help="bust: after the blend, compare each projector's modelled light with the room's, by "
                             "incidence angle, and the blended light as predicted and as rendered; the figures go "
                             "under parts.bust.diagnosis, the picture to DIR/bust_diagnosis.png")


def _defaults(args: argparse.Namespace) -> None:
    q = args.quick
    args.projector_scale = args.projector_scale or (0.12 if q else 0.25)
    args.camera_scale = args.camera_scale or (0.15 if q else 0.25)
    args.poses = args.poses or ("truth" if q else "calibrate")
    args.luts = args.luts or ("truth" if q else "response")
    args.frames = args.frames or (2 if q else 4)
    args.table_slots = args.table_slots or ("4" if q else "P25")
    args.failover_rigs = args.failover_rigs or ("P9W" if q else "P25,P9W")
    args.node_frames = args.node_frames or (20 if q else 120)


def _r(v, nd: int = 5):
    if v is None:
        return None
    v = float(v)
    return None if math.isnan(v) else round(v, nd)


# ---------------------------------------------------------------------- the in-process parts
def _light(args) -> Light:
    return Light(args.brightness_spread, args.white_spread, args.hotspot, args.vignetting)


def _content_for(room, mm_per_px: float = 4.0) -> tuple[int, int]:
    tw, th = room.scene.table.size
    return int(round(tw / mm_per_px)), int(round(th / mm_per_px))


async def part_table(args, work: Path) -> dict:
    from bench.uniformity_room import blended_rig
    slots = slots_of(args.table_slots)
    _log(f"table: {len(slots)} projectors, light {_light(args).as_dict()}")
    room = table_room(_light(args), projector_scale=args.projector_scale, camera_scale=args.camera_scale,
                      seed=args.seed)
    b = await blended_rig(room, slots, work / "table", content_size=_content_for(room), poses=args.poses,
                          luts=args.luts, frames=args.frames, headroom=args.headroom, map_scale=args.map_scale)
    white, grey = b.expected(1.0), b.expected(0.5)
    colour_before = channel_deviation(b.grey_before, grey, b.covered)
    colour_after = channel_deviation(b.grey_after, grey, b.covered)
    out = {
        "slots": len(slots),
        "before": _r(nonuniformity(b.white_before, white, b.covered)),
        "after": _r(nonuniformity(b.white_after, white, b.covered)),
        "before_flat_target": _r(nonuniformity(b.white_before, None, b.covered)),
        "after_flat_target": _r(nonuniformity(b.white_after, None, b.covered)),
        "colour_before": _r(colour_before["max"]),
        "colour_after": _r(colour_after["max"]),
        "colour_after_per_channel": [_r(v) for v in colour_after["per_channel"]],
        "colour_white_point_spread_after": _r(colour_after["white_point_spread"]),
        "covered_fraction": _r(b.covered.mean(), 4),
        "brightness_after_over_before": _r(float(np.median(b.white_after[b.covered])) /
                                           max(float(np.median(b.white_before[b.covered])), 1e-9), 4),
        "blend_captures": b.captures, "blend_seconds": round(b.seconds, 1), "maps_change_white_by": _r(b.applied, 4),
        "job": _job_figures(b.result), "notes": b.notes,
    }
    _log(f"table: non-uniformity {out['before']} -> {out['after']}, grey per channel {out['colour_after']}")
    return out


def _job_figures(result: dict) -> dict:
    keys = ("headroom", "brightness_cost", "uniformity_before", "uniformity_after", "captures", "created_at",
            "blend_id", "uncovered")
    return {k: result[k] for k in keys if isinstance(result, dict) and k in result}


async def part_wall(args, work: Path) -> dict:
    from bench.uniformity_room import blended_rig
    room, source = wall_room(_light(args), projector_scale=args.projector_scale, camera_scale=args.camera_scale,
                             seed=args.seed)
    slots = list(room.scene.slots)
    _log(f"wall: {len(slots)} projectors from {source}")
    b = await blended_rig(room, slots, work / "wall", content_size=_content_for(room), poses=args.poses,
                          luts=args.luts, frames=args.frames, headroom=args.headroom, map_scale=args.map_scale)
    before = seam_steps(b.white_before, np.where(b.covered, b.count, 0))
    after = seam_steps(b.white_after, np.where(b.covered, b.count, 0))
    out = {"source": source, "slots": len(slots),
           "seam_before": _r(before[0]["step"]) if before else None,
           "seam_after": _r(after[0]["step"]) if after else None,
           "seams": [{**s, "step": _r(s["step"])} for s in after[:8]],
           "non_uniformity_before": _r(nonuniformity(b.white_before, b.expected(1.0), b.covered)),
           "non_uniformity_after": _r(nonuniformity(b.white_after, b.expected(1.0), b.covered)),
           "blend_captures": b.captures, "job": _job_figures(b.result), "notes": b.notes}
    if not before:
        out["notes"].append("no seam found: the room's footprints do not partly overlap under the camera")
    _log(f"wall: largest seam step {out['seam_before']} -> {out['seam_after']}")
    return out


async def part_bust(args, work: Path) -> dict:
    from bench.compensation_bust import make_bust_rig
    from bench.uniformity_room import blended_rig
    room, source = bust_walls_room(_light(args), projector_scale=args.projector_scale,
                                   camera_scale=args.camera_scale, seed=args.seed)
    slots = list(room.scene.slots)
    _log(f"bust: {len(slots)} projectors from {source}")
    content = (128, 96) if args.quick else (256, 192)

    def mesh_rig(path, room_, slots_):     # the true poses and LUTs (the response job measures planar rigs)
        return make_bust_rig(path, room_, slots_, content_size=content, luts=True)

    b = await blended_rig(room, slots, work / "bust", content_size=content, poses="truth", luts="truth",
                          frames=args.frames, headroom=args.headroom, map_scale=args.map_scale, mesh_rig=mesh_rig)
    on_mesh = room.truth.surface(0).kind == 2
    mask = b.covered & on_mesh & (b.count >= 3)
    out = {"source": source, "slots": len(slots), "pixels": int(mask.sum()),
           "before": _r(nonuniformity(b.white_before, b.expected(1.0), mask, block=4)),
           "after": _r(nonuniformity(b.white_after, b.expected(1.0), mask, block=4)),
           "reach_min_max": [int(b.count[mask].min()), int(b.count[mask].max())] if mask.any() else None,
           "blend_captures": b.captures, "job": _job_figures(b.result), "notes": b.notes + ["4x4 blocks on the bust"]}
    _log(f"bust: non-uniformity where >= 3 reach {out['before']} -> {out['after']}")
    if args.diagnose:
        from bench.uniformity_diagnose import diagnose
        out["diagnosis"] = diagnose(room, work / "bust", mask, Path(args.diagnose))
        _log(f"bust: diagnosis in {Path(args.diagnose) / out['diagnosis']['picture']}: blended light "
             f"{out['diagnosis']['blended']}")
    return out


async def part_captures(args, work: Path, table: dict | None) -> dict:
    """The blend job's captures on 1 projector and on 25 (the table part's, when it ran on 25)."""
    from bench.uniformity_room import blended_rig
    out: dict = {}
    room = table_room(_light(args), projector_scale=args.projector_scale, camera_scale=args.camera_scale,
                      seed=args.seed)
    sizes = [("1", ["r2c2"]), ("25", slots_of("P25"))]
    for key, slots in sizes:
        if key == "25" and table is not None and table.get("slots") == 25:
            out["25"] = table["blend_captures"]
            continue
        b = await blended_rig(room, slots, work / f"captures-{key}", content_size=_content_for(room), poses="truth",
                              luts="truth", frames=1, headroom=args.headroom, map_scale=args.map_scale)
        out[key] = b.captures
    out["ratio_25_over_1"] = _r(out["25"] / max(out["1"], 1), 3)
    _log(f"captures: {out['1']} for 1 projector, {out['25']} for 25")
    return out


# ---------------------------------------------------------------------- node
def part_node(args) -> dict:
    """`bench node` in a child process: the blend's render-time ratio and resident-memory delta at 1080p."""
    cmd = [sys.executable, "-m", "shadowless", "bench", "node", "--frames", str(args.node_frames)]
    _log(f"node: {' '.join(cmd[2:])}")
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        raise RuntimeError(f"bench node failed: {done.stderr.strip().splitlines()[-1:]}")
    doc = json.loads(done.stdout)

    def find(key: str):
        if key in doc:
            return doc[key]
        node = doc
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                return None
            node = node[part]
        return node

    ratio, delta = find("blend.render_ratio"), find("blend.rss_delta_mb")
    if ratio is None and delta is None:
        raise Missing("`bench node` reports no blend figures (blend.render_ratio, blend.rss_delta_mb)")
    blend = doc.get("blend") if isinstance(doc.get("blend"), dict) else {}
    return {"render_ratio": ratio, "rss_delta_mb": delta, "frames": args.node_frames,
            "detail": {k: v for k, v in blend.items() if k not in ("render_ratio", "rss_delta_mb")}}


# ---------------------------------------------------------------------- the document
def _flat_figures(results: dict) -> dict:
    t, w, bu, c, f, wd, n = (results.get(k) or {} for k in ("table", "wall", "bust", "captures", "failover",
                                                           "watchdog", "node"))
    fig = {
        "table.before": t.get("before"), "table.after": t.get("after"), "table.colour_after": t.get("colour_after"),
        "wall.seam_before": w.get("seam_before"), "wall.seam_after": w.get("seam_after"),
        "bust.before": bu.get("before"), "bust.after": bu.get("after"),
        "captures.1": c.get("1"), "captures.25": c.get("25"),
        "node.render_ratio": n.get("render_ratio"), "node.rss_delta_mb": n.get("rss_delta_mb"),
        "watchdog.detect_s": wd.get("detect_s"), "watchdog.gain_error": wd.get("gain_error"),
    }
    for rig in ("P25", "P9"):
        r = (f.get(rig) or f.get(rig + "W") or {}) if f else {}
        fig[f"failover.{rig}.after"] = r.get("after")
        fig[f"failover.{rig}.frames_after_declared"] = r.get("frames_after_declared")
        fig[f"failover.{rig}.frames_after_declared_again"] = (r.get("again") or {}).get("frames_after_declared")
    return {k: fig.get(k) for k in FIGURES}


def _targets(fig: dict, results: dict) -> dict:
    out = {}
    for key, (_, target, how) in FIGURES.items():
        v = fig.get(key)
        if target is None:
            continue
        out[key] = {"value": v, "target": f"{how} {target}", "met": None if v is None else bool(v <= target)}
    t = results.get("table") or {}
    if t.get("before") is not None and t.get("after") is not None:
        out["table.after_below_before"] = {"value": [t["before"], t["after"]], "met": t["after"] < t["before"]}
    c = results.get("captures") or {}
    if c.get("1") and c.get("25") is not None:
        out["captures.25_over_1"] = {"value": c["ratio_25_over_1"], "target": "<= 2", "met": c["ratio_25_over_1"] <= 2}
    w = results.get("wall") or {}
    if w.get("seam_before") is not None and w.get("seam_after") is not None:
        out["wall.seam_after_below_before"] = {"value": [w["seam_before"], w["seam_after"]],
                                               "met": w["seam_after"] < w["seam_before"]}
    return out


async def _run_parts(args, work: Path, parts: list[str]) -> tuple[dict, dict]:
    results: dict = {}
    missing: dict = {}

    async def one(name, fn):
        t = time.perf_counter()
        try:
            results[name] = await fn()
            results[name]["wall_s"] = round(time.perf_counter() - t, 1)
        except Missing as exc:
            missing[name] = str(exc)
            _log(f"{name}: not measured: {exc}")
        except Exception as exc:    # a part that fails says why and the others still run
            missing[name] = f"failed: {type(exc).__name__}: {exc}"
            _log(f"{name}: FAILED\n{traceback.format_exc()}")

    if "table" in parts:
        await one("table", lambda: part_table(args, work))
    if "wall" in parts:
        await one("wall", lambda: part_wall(args, work))
    if "bust" in parts:
        await one("bust", lambda: part_bust(args, work))
    if "captures" in parts:
        await one("captures", lambda: part_captures(args, work, results.get("table")))
    if "failover" in parts or "watchdog" in parts:
        from bench.uniformity_live import part_failover, part_watchdog
        if "failover" in parts:
            await one("failover", lambda: part_failover(args, work, _light(args)))
        if "watchdog" in parts:
            await one("watchdog", lambda: part_watchdog(args, work, _light(args)))
    if "node" in parts:
        await one("node", lambda: asyncio.to_thread(part_node, args))
    return results, missing


def run(args: argparse.Namespace) -> int:
    _defaults(args)
    parts = list(args.only or PARTS)
    t0 = time.perf_counter()
    params = {k: v for k, v in vars(args).items() if not k.startswith("_") and k not in ("command", "bench")}
    if args.keep:
        work = Path(args.keep)
        work.mkdir(parents=True, exist_ok=True)
        results, missing = asyncio.run(_run_parts(args, work, parts))
    else:
        with tempfile.TemporaryDirectory(prefix="bench-uniformity-") as tmp:
            results, missing = asyncio.run(_run_parts(args, Path(tmp), parts))
    fig = _flat_figures(results)
    for key, (part, _, _) in FIGURES.items():
        if part not in parts:
            missing.setdefault(part, "not run (--only)")
    doc = {"benchmark": "uniformity", "machine": machine(), "parameters": params, **fig,
           "targets": _targets(fig, results), "missing": missing, "parts": results,
           "wall_s": round(time.perf_counter() - t0, 1)}
    print(json.dumps(doc, indent=2, default=_json_default))
    return 0


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (set, frozenset, tuple)):
        return list(v)
    return str(v)
