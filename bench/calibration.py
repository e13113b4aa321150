"""`shadowless bench calibration`: captures, time and error of the sequential and the
multiplexed calibration modes for rigs of several sizes, in the virtual room, on the table
or (``--surface bust``) on the plaster bust standing on it.

The coordinator's ``calibrate`` job runs in-process against :class:`sim.room.Room` through
:class:`shadowless.room_driver.RoomDriver` (the rig driver whose projectors and cameras are
the room's), so the figures measure calibration itself, not gRPC or the node processes. The
table -> camera mapping comes from known table points written from the room's truth with
click noise (:func:`table_points_from_truth`), as an operator would click them; on the bust,
landmarks clicked on it the same way (:func:`landmarks_from_truth`) pose the camera with them.
Errors are against the room's ground truth: over the table (:func:`planar_errors`), or over the
bust's surface each projector lights and the camera sees (:func:`mesh_errors`).

This module is also the test kit of ``tests/coordinator/calibration`` (rigs, truth-derived
point files and error measures); it may import ``sim``, the coordinator never does.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from protos import cli_types
from scipy.spatial import cKDTree

from bench.machine import machine
from imaging.calibration import planar
from imaging.calibration.points import PointSet, write_points
from imaging.calibration.threed import project
from coordinator.jobs import Progress
from coordinator.rig import Rig, init_rig
from protos.spaces import content_to_table
from shadowless.room_driver import RoomDriver
from sim.mesh import bust, save_mesh
from sim.room import Room
from sim.scene import SUBSETS, reference_scene

#: Which projectors a rig of N uses on the reference 5x5 array (spread out, centre first).
RIG_SUBSETS = {1: ["r2c2"], 4: ["r1c1", "r1c3", "r3c1", "r3c3"]}


def rig_slots(n: int) -> list[str]:
    """Slots of an N-projector rig on the 5x5 array: the named subsets for 1, 9 (P9W), 25; else the first N."""
    if n in RIG_SUBSETS:
        return list(RIG_SUBSETS[n])
    if n == 9:
        return list(SUBSETS["P9W"])
    if n == 25:
        return list(SUBSETS["P25"])
    if not 1 <= n <= 25:
        raise ValueError(f"the reference rig has 1..25 projectors, not {n}")
    return list(SUBSETS["P25"][:n])


def make_rig(path: Path, room, slots: list[str], *, content_size: tuple[int, int] = (1200, 600)) -> Rig:
    """A rig directory whose slots are ``slots`` at the room's projector resolution."""
    w, h = room.projector_size(slots[0])
    init_rig(path, name=f"bench-{len(slots)}", slots=slots, width=w, height=h, content_width=content_size[0],
             content_height=content_size[1])
    return Rig(path)


def table_points_from_truth(room, path: Path | None = None, *, camera: int = 0, grid: tuple[int, int] = (5, 3),
                            click_noise_px: float = 0.3, inset_mm: float = 40.0, seed: int = 0) -> list[PointSet]:
    """Known table points (marks on a grid over the table) as an operator clicks them in the camera.

    The pixels are the true projections with Gaussian click noise (marks outside the image are left
    out); written to
    ``path`` as a points file when given.
    """
    rng = np.random.default_rng(seed)
    tw, th = room.scene.table.size
    xs = np.linspace(-tw / 2 + inset_mm, tw / 2 - inset_mm, grid[0])
    ys = np.linspace(th / 2 - inset_mm, -th / 2 + inset_mm, grid[1])
    xy = np.array([[x, y] for y in ys for x in xs])
    H = room.truth.table_to_camera_homography(camera)
    px = planar.apply_homography(H, xy) + rng.normal(0.0, click_noise_px, (len(xy), 2))
    W, Hc = room.camera_size(camera)
    seen = (px[:, 0] > 5) & (px[:, 1] > 5) & (px[:, 0] < W - 6) & (px[:, 1] < Hc - 6)   # marks the camera sees
    xy, px = xy[seen], px[seen]
    names = tuple(f"mark {i + 1}" for i in range(len(xy)))
    sets = [PointSet("world", camera, names, np.column_stack([xy, np.zeros(len(xy))]), px)]
    if path is not None:
        write_points(path, sets)
    return sets


def landmarks_from_truth(room, path: Path | None = None, *, camera: int = 0, count: int = 20,
                         click_noise_px: float = 0.5, model_transform: tuple[np.ndarray, np.ndarray] | None = None,
                         seed: int = 0) -> list[PointSet]:
    """Mesh landmarks clicked in the camera: surface points of the mesh the camera sees, spread over it.

    ``model_transform`` (R, t) with ``world = R model + t``: write the points in
    the model frame (as a scanned mesh would have them), else in the world frame.
    """
    rng = np.random.default_rng(seed)
    surf = room.truth.surface(camera)
    ys, xs = np.nonzero(surf.kind == 2)
    if len(ys) < count:
        raise ValueError("the camera sees too little of the mesh for landmarks")
    # spread: farthest-point sampling over the seen mesh pixels
    pix = np.column_stack([xs, ys]).astype(np.float64)
    chosen = [int(rng.integers(len(pix)))]
    d = np.linalg.norm(pix - pix[chosen[0]], axis=1)
    for _ in range(count - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(pix - pix[k], axis=1))
    X = surf.points[ys[chosen], xs[chosen]].astype(np.float64)
    cam = room.truth.camera(camera)
    h = (X @ cam.R.T + cam.t) @ cam.K.T
    px = h[:, :2] / h[:, 2:3] + rng.normal(0.0, click_noise_px, (len(X), 2))
    frame = "world"
    if model_transform is not None:
        R, t = model_transform
        X = (X - np.asarray(t)) @ np.asarray(R)   # model = R^T (world - t)
        frame = "model"
    sets = [PointSet(frame, camera, tuple(f"landmark {i + 1}" for i in range(len(X))), X, px)]
    if path is not None:
        write_points(path, sets)
    return sets


def board_albedo(room, spec, *, camera: int = 0, supersample: int = 4, px_per_mm: int = 2) -> np.ndarray:
    """(H, W) float32 albedo factor a camera sees when a ChArUco board lies on the table: the board image
    mapped through the true table -> camera homography, integrated over each camera pixel (supersampled),
    black squares reflecting 8 % of what white ones do."""
    board_img = spec.board().generateImage((round(spec.squares_x * spec.square_mm * px_per_mm),
                                            round(spec.squares_y * spec.square_mm * px_per_mm)), marginSize=0)
    ss, ppm = supersample, px_per_mm
    S = np.array([[1 / ppm, 0, 0.5 / ppm], [0, 1 / ppm, 0.5 / ppm], [0, 0, 1]])       # board image px -> board mm
    B = np.array([[1, 0, spec.origin_mm[0]], [0, -1, spec.origin_mm[1]], [0, 0, 1]])  # board mm -> table mm
    U = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1]])            # camera px -> supersampled px
    W, H = room.camera_size(camera)
    fine = cv2.warpPerspective(board_img.astype(np.float32) / 255.0, U @ room.truth.table_to_camera_homography(camera) @ B @ S,
                               (W * ss, H * ss), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
    return (0.08 + 0.92 * cv2.resize(fine, (W, H), interpolation=cv2.INTER_AREA)).astype(np.float32)


def planar_errors(room, slot: str, pose: np.ndarray, content_size: tuple[int, int], *, step: int = 4) -> tuple[float, float]:
    """RMS and max distance (projector px) between ``pose`` and the true content -> projector homography,
    over the content pixels (the table) that land inside the projector's image."""
    truth = room.truth.content_to_projector_homography(slot, content_size)
    w, h = content_size
    g = np.stack(np.meshgrid(np.arange(0, w, step), np.arange(0, h, step)), -1).reshape(-1, 2).astype(np.float64)
    t = planar.apply_homography(truth, g)
    pw, ph = room.projector_size(slot)
    inside = (t[:, 0] >= -0.5) & (t[:, 1] >= -0.5) & (t[:, 0] <= pw - 0.5) & (t[:, 1] <= ph - 0.5)
    return planar.homography_difference(pose, truth, g[inside])


def mesh_errors(room, slot: str, P: np.ndarray, *, camera: int = 0) -> tuple[float, float, int]:
    """RMS, max (projector px) and count: ``P`` against the truth over the mesh surface the camera sees
    and the projector lights (the visible surface)."""
    surf = room.truth.surface(camera)
    pc = room.truth.projector_coordinates(slot, camera)
    vis = (surf.kind == 2) & np.isfinite(pc[..., 0])
    X = surf.points[vis].astype(np.float64)
    est, _ = project(P, X)
    true, _ = project(room.truth.projector(slot).P, X)
    d = np.linalg.norm(est - true, axis=1)
    return float(np.sqrt(np.mean(d ** 2))), float(d.max()), int(len(d))


def mesh_vertex_errors(room, slot: str, P: np.ndarray, vertices: np.ndarray, *, camera: int = 0) -> tuple[float, float, int]:
    """Where the calibrated system draws each mesh vertex (``P`` applied to the *registered* vertices)
    against where it belongs (the true projection of the true vertex), over the vertices of the visible
    surface: RMS, max (projector px) and count. With a mesh registered from landmarks, registration and
    projector errors partly cancel; this measures what the audience sees."""
    true_v = room.scene.mesh.vertices.astype(np.float64)
    surf = room.truth.surface(camera)
    pc = room.truth.projector_coordinates(slot, camera)
    vis = (surf.kind == 2) & np.isfinite(pc[..., 0])
    idx = np.unique(cKDTree(true_v).query(surf.points[vis].astype(np.float64))[1])
    est, _ = project(P, np.asarray(vertices, np.float64)[idx])
    true, _ = project(room.truth.projector(slot).P, true_v[idx])
    d = np.linalg.norm(est - true, axis=1)
    return float(np.sqrt(np.mean(d ** 2))), float(d.max()), int(len(d))


# ---------------------------------------------------------------------- the benchmark
def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Calibrate rigs of several sizes in the virtual room, sequential (Gray codes, one projector after another)\n"
        "and multiplexed (every projector at once), and print one JSON document: captures, wall time and the\n"
        "RMS / max error of the poses against the room's truth (projector pixels, over the table, or with\n"
        "--surface bust over the bust's surface each projector lights: 3x4 poses)."
    )
    parser.epilog = (
        "examples:\n"
        "  shadowless bench calibration\n"
        "  shadowless bench calibration --projectors 1,25 --modes multiplexed\n"
        "  shadowless bench calibration --surface bust --projectors 1,25      # both modes side by side on the bust\n"
    )
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--surface", choices=("table", "bust"), default="table",
                        help="what the projectors light: the table (homographies) or the bust on it (3x4 poses)")
    parser.add_argument("--projectors", type=cli_types.int_list(1, 25), default="1,9,25", help="rig sizes, comma separated (default 1,9,25)")
    parser.add_argument("--modes", type=cli_types.names, default="sequential,multiplexed", help="modes to run (default both)")
    parser.add_argument("--projector-scale", type=float, default=0.25, help="room projector resolution scale (default 0.25)")
    parser.add_argument("--camera-scale", type=float, default=0.25, help="room camera resolution scale (default 0.25)")
    parser.add_argument("--seed", type=int, default=0, help="room seed (unit variation, noise)")
    parser.add_argument("--click-noise", type=float, default=0.3, help="px of noise on the known table points (default 0.3)")
    parser.add_argument("--seconds-per-capture", type=float, default=0.3,
                        help="for est_rig_s: a real rig's time per capture (swap latency + settle + exposure; default 0.3)")


async def _calibrate(driver: RoomDriver, params: dict, what: str) -> dict:
    """The calibrate job on ``driver``, its progress on stderr every few seconds (a sequential run of
    25 projectors takes hundreds of captures)."""
    job = asyncio.ensure_future(driver.run("calibrate", params))
    last = None
    while not job.done():
        await asyncio.wait([job], timeout=5.0)
        now = next((e for e in reversed(driver.events) if isinstance(e, Progress)), None)
        if now is not None and now != last and not job.done():
            print(f"{what}: {now.stage} {now.item} {now.done}/{now.total}".replace("  ", " "), file=sys.stderr)
            last = now
    return job.result()


async def _run_one(room, slots: list[str], mode: str, table_points, workdir: Path, seconds_per_capture: float) -> dict:
    rig = make_rig(workdir, room, slots)
    driver = RoomDriver(room, rig)
    points_doc = {"frame": "world", "points": [{"xyz": list(map(float, x)), "pixel": list(map(float, p)), "camera": 0}
                                              for x, p in zip(table_points[0].xyz, table_points[0].pixels)]}
    t0 = time.perf_counter()
    result = await _calibrate(driver, {"mode": mode, "table_points": points_doc, "settle_s": 0.0},
                              f"{len(slots)} projector(s), {mode}")
    wall = time.perf_counter() - t0
    content = (rig.config.content_width, rig.config.content_height)
    errs = {s: planar_errors(room, s, rig.slot(s).pose.matrix, content) for s in slots}
    rms = [e[0] for e in errs.values()]
    mx = [e[1] for e in errs.values()]
    # the same poses with the clicked table mapping replaced by the true one: the projector calibration's own error
    H_est = np.array(json.loads((rig.path / "calibration" / "cameras.json").read_text())["cameras"][0]["table_to_camera"])
    fix = np.linalg.inv(H_est) @ room.truth.table_to_camera_homography(0)
    c2t = content_to_table(content, room.scene.table.size)
    own = {s: planar_errors(room, s, rig.slot(s).pose.matrix @ np.linalg.inv(c2t) @ fix @ c2t, content) for s in slots}
    return {"captures": result["captures"], "wall_s": round(wall, 3), "wall_s_per_capture": round(wall / result["captures"], 4),
            "est_rig_s": round(result["captures"] * seconds_per_capture, 1),
            "rms_px_worst_slot": round(max(rms), 4), "rms_px_mean": round(float(np.mean(rms)), 4),
            "max_px": round(max(mx), 4),
            "exact_table_rms_px_worst_slot": round(max(e[0] for e in own.values()), 4),
            "exact_table_max_px": round(max(e[1] for e in own.values()), 4),
            "fit_rms_px_mean": round(float(np.mean([d["rms_px"] for d in result["slots"].values()])), 4)}


async def _run_one_bust(room, slots: list[str], mode: str, files: dict[str, Path], workdir: Path,
                        seconds_per_capture: float) -> dict:
    """One calibration of ``slots`` on the bust; errors over the surface each projector lights (:func:`mesh_errors`)."""
    rig = make_rig(workdir, room, slots)
    driver = RoomDriver(room, rig)
    t0 = time.perf_counter()
    result = await _calibrate(driver, {"mode": mode, "mesh": str(files["mesh"]), "table_points": str(files["table"]),
                                       "landmarks": str(files["landmarks"]), "settle_s": 0.0},
                              f"{len(slots)} projector(s) on the bust, {mode}")
    wall = time.perf_counter() - t0
    errs = {s: mesh_errors(room, s, rig.slot(s).pose.matrix) for s in slots}
    rms = [e[0] for e in errs.values()]
    print(f"{len(slots)} projector(s), {mode}: {result['captures']} captures, worst rms {max(rms):.3f} px",
          file=sys.stderr)
    return {"captures": result["captures"], "wall_s": round(wall, 3), "wall_s_per_capture": round(wall / result["captures"], 4),
            "est_rig_s": round(result["captures"] * seconds_per_capture, 1),
            "rms_px_worst_slot": round(max(rms), 4), "rms_px_mean": round(float(np.mean(rms)), 4),
            "max_px": round(max(e[1] for e in errs.values()), 4),
            "surface_points_min": min(e[2] for e in errs.values()),
            "fit_rms_px_mean": round(float(np.mean([d["rms_px"] for d in result["slots"].values()])), 4)}


def _bust_files(room, directory: Path, click_noise: float, seed: int) -> dict[str, Path]:
    """The operator's inputs for the bust: its mesh (in the world frame), table marks and landmarks clicked in the camera."""
    files = {"mesh": directory / "bust.obj", "table": directory / "table.json", "landmarks": directory / "landmarks.json"}
    save_mesh(bust(), files["mesh"])
    table_points_from_truth(room, files["table"], click_noise_px=click_noise, seed=seed)
    landmarks_from_truth(room, files["landmarks"], count=20, click_noise_px=0.5, seed=seed)
    return files


def run(args: argparse.Namespace) -> int:
    sizes, modes = list(args.projectors), list(args.modes)
    for m in modes:
        if m not in ("sequential", "multiplexed"):
            raise SystemExit(f"unknown mode {m!r}: sequential or multiplexed")
    on_bust = args.surface == "bust"
    t_room = time.perf_counter()
    room = Room(reference_scene(projector_scale=args.projector_scale, camera_scale=args.camera_scale, seed=args.seed,
                                surface="bust" if on_bust else "table"), seed=args.seed)
    room.prepare(0)
    setup_s = time.perf_counter() - t_room
    figures: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="bench-calibration-") as tmp:
        if on_bust:
            files = _bust_files(room, Path(tmp), args.click_noise, args.seed)
        else:
            points = table_points_from_truth(room, click_noise_px=args.click_noise, seed=args.seed)
        for n in sizes:
            slots = rig_slots(n)
            figures[str(n)] = {}
            for mode in modes:
                work = Path(tmp) / f"{n}-{mode}"
                if on_bust:
                    figures[str(n)][mode] = asyncio.run(_run_one_bust(room, slots, mode, files, work, args.seconds_per_capture))
                else:
                    figures[str(n)][mode] = asyncio.run(_run_one(room, slots, mode, points, work, args.seconds_per_capture))
    summary = {}
    if sizes:
        lo, hi = str(min(sizes)), str(max(sizes))
        for mode in modes:
            summary[f"{mode}_captures_ratio_largest_to_smallest"] = round(
                figures[hi][mode]["captures"] / figures[lo][mode]["captures"], 3)
        if "multiplexed" in modes and "sequential" in modes:
            summary["sequential_to_multiplexed_wall_ratio_largest"] = round(
                figures[hi]["sequential"]["wall_s"] / figures[hi]["multiplexed"]["wall_s"], 2)
            summary["sequential_to_multiplexed_captures_ratio_largest"] = round(
                figures[hi]["sequential"]["captures"] / figures[hi]["multiplexed"]["captures"], 2)
        summary["side_by_side"] = {n: {m: {"captures": figures[n][m]["captures"],
                                           "rms_px_worst_slot": figures[n][m]["rms_px_worst_slot"]} for m in modes}
                                   for n in figures}
    doc = {
        "benchmark": "calibration",
        "parameters": {"surface": args.surface, "projectors": sizes, "modes": modes, "projector_scale": args.projector_scale,
                       "camera_scale": args.camera_scale, "seed": args.seed, "click_noise_px": args.click_noise,
                       "projector_size": list(room.projector_size("r0c0")), "camera_size": list(room.camera_size(0)),
                       "table_mapping": "15 known table points with click noise"
                                        + (", 20 landmarks on the bust with 0.5 px click noise" if on_bust else ""),
                       "room_setup_s": round(setup_s, 3),
                       "seconds_per_capture": args.seconds_per_capture},
        "figures": figures,
        "summary": summary,
        "notes": "in-process room (no gRPC, no node processes): wall_s is calibration compute plus simulated captures "
                 "(the room's first capture of each projector includes its one-off precomputation); est_rig_s = captures x "
                 "seconds_per_capture. Errors: poses against the room's truth in projector px, "
                 + ("over the bust's surface points the camera sees and each projector lights (the true points "
                    "projected through the estimated vs the true 3x4 pose; the camera posed from clicked table marks "
                    "and landmarks)" if on_bust else
                    "over the table; exact_table_*: the same poses with the clicked table -> camera mapping replaced by "
                    "the true one (the projector calibration's own error)"),
        "machine": machine(),
    }
    print(json.dumps(doc, indent=2))
    return 0
