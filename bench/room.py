"""`shadowless bench room`: capture speed of the virtual room and light drop under a hand per projector subset.

Prints one JSON document:

* ``capture``: seconds per capture (median of ``--repeat``) for 1, 9 and 25
  projectors at the default (648 x 486) and the full (2592 x 1944) camera
  resolution, projectors at 320 x 200. ``fresh`` shows new frames before every
  capture (what calibration does: nothing cached), ``cached`` repeats the same
  frames (a moving hand, static content). Ratios are to 1 projector, measured
  in the same run.
* ``light_drop``: for each named subset (P1 ... P25) with a flat hand at
  ``--height`` over a grid of table positions, from the room's ground-truth
  light-drop map (fraction of light lost at each table point):

  - ``max``: largest drop;
  - ``mean``: mean drop over the affected area (drop > 1 %);
  - ``area_below_50_mm2``: table area left with less than 50 % of its light;
  - ``umbra_mm2``: table area that lost at least 90 % (the umbra);
  - ``transition_mm``: how far one travels from the 10 %-of-max contour to the
    region within 90 % of the max (median over the contour). 0 means the drop
    jumps from under 10 % to over 90 % of its max between neighbouring camera
    pixels (~2 mm): a hard edge; a synthetic-aperture shadow fades in over tens
    of mm or more. The map is geometric (pinhole visibility): lens blur and the
    projector pixel's footprint soften any real edge by about one projector
    pixel more (~4 mm at the default scale);
  - ``max_step``: largest drop difference between neighbouring camera pixels
    (1.0 = a black shadow right next to full light).

  Per-position figures are averaged (``max`` and ``max_step``: the maximum).
* ``touch``: the same with a fingertip touching the table (paper Fig. 'planar_result', bottom).
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from sim.drop_figures import drop_statistics

from bench.machine import machine
from sim.hand import Hand
from sim.room import Room
from sim.scene import SUBSETS, reference_scene


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=5, help="captures timed per configuration (median; default 5)")
    parser.add_argument("--positions", type=int, default=3, help="hand positions per table axis (default 3: a 3x3 grid)")
    parser.add_argument("--height", type=float, default=200.0, help="height of the hand's lowest point, mm (default 200)")
    parser.add_argument("--yaw", type=float, default=0.0, help="direction the fingers point, deg from +y (default 0)")
    parser.add_argument("--no-full", action="store_true", help="skip the full camera resolution (slow to prepare)")
    parser.add_argument("--quick", action="store_true", help="2 repeats, a 2x2 grid, no full resolution (a smoke run)")
    parser.add_argument("--seed", type=int, default=0)


def _time_captures(room, slots: list[str], repeat: int, *, fresh: bool) -> dict:
    rng = np.random.default_rng(0)
    w, h = room.projector_size(slots[0])
    frames = [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(2)]
    room.set_active(slots)
    for s in slots:
        room.set_frame(s, frames[0])
    room.capture()  # warm the caches
    wall, cpu = [], []
    for k in range(repeat):
        if fresh:
            for s in slots:
                room.set_frame(s, frames[(k + 1) % 2])
        t0, c0 = time.perf_counter(), time.process_time()
        room.capture()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {"seconds": round(statistics.median(wall), 4), "cpu_seconds": round(statistics.median(cpu), 4)}


def capture_speed(*, camera_scale: float, repeat: int, seed: int) -> dict:
    t0 = time.perf_counter()
    room = Room(reference_scene(projector_scale=0.25, camera_scale=camera_scale, seed=seed), seed=seed)
    room.prepare()
    prepare = time.perf_counter() - t0
    out = {"camera": list(room.camera_size()), "projector": list(room.projector_size("r0c0")), "prepare_seconds": round(prepare, 2)}
    sets = {"1": ["r2c2"], "9": SUBSETS["P9D"], "25": SUBSETS["P25"]}
    for mode in ("fresh", "cached"):
        timings = {n: _time_captures(room, slots, repeat, fresh=mode == "fresh") for n, slots in sets.items()}
        base = timings["1"]["seconds"]
        for t in timings.values():
            t["ratio_to_1"] = round(t["seconds"] / base, 2) if base > 0 else None
        out[mode] = timings
    return out


def _pixel_areas(points: np.ndarray) -> np.ndarray:
    """mm^2 of table each camera pixel covers, from the surface points of neighbouring pixels."""
    p = np.nan_to_num(points.astype(np.float64))
    dx = np.zeros_like(p)
    dy = np.zeros_like(p)
    dx[:, :-1] = p[:, 1:] - p[:, :-1]
    dx[:, -1] = dx[:, -2]
    dy[:-1] = p[1:] - p[:-1]
    dy[-1] = dy[-2]
    return np.linalg.norm(np.cross(dx, dy), axis=-1)


def light_drop(*, positions: int, height: float, yaw: float, seed: int, pose: str = "flat") -> dict:
    room = Room(reference_scene(seed=seed), seed=seed)
    surf = room.truth.surface()
    on = surf.kind == 1
    area = np.where(on, _pixel_areas(surf.points), 0.0)
    xs = np.linspace(-400.0, 400.0, positions) if positions > 1 else np.array([0.0])
    ys = np.linspace(-150.0, 150.0, positions) if positions > 1 else np.array([0.0])
    per: dict[str, list[dict]] = {name: [] for name in SUBSETS}
    for y in ys:
        for x in xs:
            room.set_occluders([Hand(position=(float(x), float(y)), height=height, yaw_deg=yaw, pose=pose)])
            for name, slots in SUBSETS.items():
                room.set_active(slots)
                s = drop_statistics(room.truth.light_drop(), on, area)
                s["position"] = [float(x), float(y)]
                per[name].append(s)
    summary = {}
    for name, rows in per.items():
        widths = [r["transition_mm"] for r in rows if r["transition_mm"] is not None]
        summary[name] = {
            "projectors": len(SUBSETS[name]),
            "max": max(r["max"] for r in rows),
            "mean": round(float(np.mean([r["mean"] for r in rows])), 4),
            "area_below_50_mm2": round(float(np.mean([r["area_below_50_mm2"] for r in rows])), 1),
            "umbra_mm2": round(float(np.mean([r["umbra_mm2"] for r in rows])), 1),
            "transition_mm": round(float(np.mean(widths)), 2) if widths else None,
            "max_step": max(r["max_step"] for r in rows),
            "positions": rows,
        }
    return summary


def run(args: argparse.Namespace) -> int:
    repeat, positions, full = args.repeat, args.positions, not args.no_full
    if args.quick:
        repeat, positions, full = 2, 2, False
    doc: dict = {
        "benchmark": "room",
        "machine": machine(),
        "parameters": {"repeat": repeat, "positions": positions, "height_mm": args.height, "yaw_deg": args.yaw, "full": full, "seed": args.seed},
    }
    capture = {"default": capture_speed(camera_scale=0.25, repeat=repeat, seed=args.seed)}
    if full:
        capture["full"] = capture_speed(camera_scale=1.0, repeat=max(2, repeat // 2), seed=args.seed)
    doc["capture"] = capture
    drop = light_drop(positions=positions, height=args.height, yaw=args.yaw, seed=args.seed)
    doc["light_drop"] = drop
    touch = light_drop(positions=1, height=0.0, yaw=args.yaw, seed=args.seed, pose="point")
    doc["touch"] = {name: {k: v for k, v in s.items() if k != "positions"} for name, s in touch.items()}
    doc["targets"] = {
        "capture_25_default_fresh_under_0_5_s": capture["default"]["fresh"]["25"]["seconds"] < 0.5,
        "p1_leaves_an_umbra": drop["P1"]["umbra_mm2"] > 0,
        "p25_leaves_no_umbra": drop["P25"]["umbra_mm2"] == 0,
    }
    print(json.dumps(doc, indent=1))
    return 0
