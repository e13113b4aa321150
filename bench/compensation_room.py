"""`shadowless bench compensation_room`: blur compensation measured in the virtual room.

The coordinator's jobs (``calibrate``, ``response``, ``transport``, ``compensate``,
``compensate_sequence``) run in-process against :class:`sim.room.Room` through
:class:`shadowless.room_driver.RoomDriver`, which renders what every node would output (the
node's warp, gain and LUT: :func:`protos.spaces.warp_content`) into the room, so the figures
measure the method, not gRPC or node processes. Reported: captures and time of each stage, the
fitted response against the room's gamma, the measured ``L`` against the room's ground-truth
transport (relative Frobenius error), solve times of ours for a 1- and a 25-projector rig and
of the per-projector baseline, and PSNR/SSIM of the image captured without compensation, with
the baseline and with ours, plus the side-by-side picture.

The baseline's matrices ``L_i`` are measured one projector at a time; a projector alone
gives the camera 1/N of the light, so by default its captures use an N times longer
exposure (``--baseline-exposure``; the room's camera can), so each ``L_i`` is measured at
the signal level ``L`` is.

This module is also the test kit of ``tests/coordinator/compensation/test_job_*``: the
ground-truth transport (:func:`truth_transport`, built on the node's lookup
:func:`bilinear_warp_matrix`), the demo picture and the calibration points. It may import
``sim``; the coordinator never does.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path
from protos import cli_types
from typing import Callable

import cv2
import numpy as np
import scipy.sparse as sp
from skimage import data as skimage_data

from bench.calibration import make_rig, table_points_from_truth
from bench.machine import machine
from imaging.compensation.geometry import camera_target, inscribed_region
from coordinator.compensation.image_param import encode_image_array, prepare_image
from coordinator.compensation.options import MOTION_FLOWS
from imaging.compensation.quality import quality
from imaging.compensation.ridge import RidgeProblem, best_scale
from imaging.compensation.solver import solve
from imaging.compensation.transport import load_transport, transport_error
from protos.spaces import bilinear_taps, projector_samples
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import SUBSETS, reference_scene


# ---------------------------------------------------------------------- the test kit
def bilinear_warp_matrix(pose: np.ndarray, projector_size: tuple[int, int], content_size: tuple[int, int]) -> sp.csr_matrix:
    """The node's content lookup as a matrix: ``(w*h, W*H)`` CSR float64, projector px x content px.

    Row ``v * w + u`` holds the bilinear weights of the four content texels around
    ``pose^-1 (u, v)`` (texels outside the content weigh 0): :func:`protos.spaces.projector_samples`
    and :func:`protos.spaces.bilinear_taps`, the one definition of what a node samples.
    """
    w, h = (int(v) for v in projector_size)
    x, y = projector_samples(pose, (w, h))
    rows, cols, vals = [], [], []
    for index, weight in bilinear_taps(x, y, content_size):
        ok = weight > 0
        rows.append(np.flatnonzero(ok))
        cols.append(index[ok])
        vals.append(weight[ok])
    cw, ch = (int(v) for v in content_size)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(w * h, cw * ch))


def truth_transport(transport_of: Callable[[str], sp.spmatrix], black_of: Callable[[str], np.ndarray], rig,
                    slots: list[str], *, exposure: float = 1.0) -> sp.csr_matrix:
    """The rig's true light transport, content px -> camera px, as the jobs measure it.

    ``sum_i T_i B_i g_i mean_c(1 - black_ic)``: the room's projector -> camera transport
    ``T_i`` (``room.truth.transport`` or ``RoomClient.transport``), the node's bilinear lookup
    ``B_i`` through the slot's stored pose, its gain ``g_i``, and the light a linearised
    input adds above black (ideal LUTs); ``exposure`` scales the camera like
    ``Room.capture(exposure=)`` relative to the camera's own.
    """
    parts = truth_transport_parts(transport_of, black_of, rig, slots, exposure=exposure)
    return sp.csr_matrix(sum(parts.values()), dtype=np.float32)


def truth_transport_parts(transport_of: Callable[[str], sp.spmatrix], black_of: Callable[[str], np.ndarray], rig,
                          slots: list[str], *, exposure: float = 1.0) -> dict[str, sp.csr_matrix]:
    """Each slot's term ``T_i B_i g_i mean_c(1 - black_ic)`` of :func:`truth_transport`, float64 CSR of shape
    (camera px, content px), by slot: the rig's truth is their sum, a slot's own truth (the per-projector
    baseline's) its term, so a bench that needs both builds each term once."""
    cw, ch = rig.config.content_width, rig.config.content_height
    out = {}
    for s in slots:
        st = rig.slot(s)
        B = bilinear_warp_matrix(st.pose.matrix, (st.width, st.height), (cw, ch))
        out[s] = (sp.csr_matrix(transport_of(s), dtype=np.float64) @ B) * (st.gain * float(np.mean(1 - black_of(s))) * exposure)
    return out


def points_doc(points) -> dict:
    """Known table points as the calibration job's inline points document."""
    return {"frame": "world", "points": [{"xyz": [float(v) for v in x], "pixel": [float(v) for v in p], "camera": 0}
                                        for x, p in zip(points[0].xyz, points[0].pixels)]}


def demo_image(size: tuple[int, int]) -> np.ndarray:
    """scikit-image's astronaut, centre-cropped to ``size`` (w, h)'s aspect and resized: (h, w, 3) uint8."""
    img = skimage_data.astronaut()
    w, h = size
    ih, iw = img.shape[:2]
    if iw / ih > w / h:
        cw = round(ih * w / h)
        img = img[:, (iw - cw) // 2:(iw - cw) // 2 + cw]
    else:
        cht = round(iw * h / w)
        img = img[(ih - cht) // 2:(ih - cht) // 2 + cht]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


# ---------------------------------------------------------------------- the benchmark
def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Blur compensation in the virtual room, end to end through the coordinator's jobs (in-process):\n"
        "calibration, luminance responses, light transport (ours: every projector at once; baseline: one\n"
        "projector at a time), solve, and the captured quality of none / baseline / ours. One JSON document."
    )
    parser.add_argument("--projector-scale", type=float, default=0.5,
                        help="room projector resolution (default 0.5: 640x400, about 2.5 mm per pixel on the table)")
    parser.add_argument("--camera-scale", type=float, default=0.25, help="room camera resolution (default 0.25: 648x486)")
    parser.add_argument("--content-size", type=cli_types.size, default="300x150", metavar="WxH",
                        help="rig content size (default 300x150: 4 mm/px, coarser than a projector pixel, so each projector "
                             "alone can render the content and the per-projector baseline has blur to undo; at 600x300 "
                             "a projector pixel spans about 1.2 content px and the baseline's L_i amplify camera noise)")
    parser.add_argument("--aperture", type=float, default=10.0, help="projector lens aperture, mm (defocus; default 10)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-noise", action="store_true", help="camera without shot/read noise (still 12-bit)")
    parser.add_argument("--radius", type=int, default=2, help="PSF recovery radius (default 2)")
    parser.add_argument("--response-frames", type=int, default=1, help="captures averaged per grey pattern (default 1)")
    parser.add_argument("--frames", type=int, default=1, help="captures averaged per dot pattern, ours (default 1)")
    parser.add_argument("--baseline-frames", type=int, default=None, help="captures averaged per pattern, baseline (default: --frames)")
    parser.add_argument("--baseline-exposure", type=float, default=None,
                        help="camera exposure of the baseline's single-projector captures (default: N)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the per-projector baseline")
    parser.add_argument("--single", action="store_true", help="skip the 1-projector rig (time ratio)")
    parser.add_argument("--max-iter", type=int, default=300)
    parser.add_argument("--regularization", type=float, default=None, metavar="MU",
                        help="ridge weight of the solves, relative to ||L||^2 (default: the compensate job's)")
    parser.add_argument("--eval-frames", type=int, default=8, help="captures averaged per evaluated result (default 8)")
    parser.add_argument("--video-frames", type=int, default=20, help="frames of the compensated sequence (0 skips it)")
    parser.add_argument("--video-iterations", type=int, default=4, help="solver iterations per sequence frame")
    parser.add_argument("--video-motion", choices=MOTION_FLOWS, default="fast",
                        help="the sequence's motion start (--motion; default fast); unless off, the same sequence "
                             "is also solved with the correction kept in place (sequence_still)")
    parser.add_argument("--out", type=Path, default=None, help="copy the side-by-side picture and the rig's JSON here")


def _log(msg: str) -> None:
    print(f"[bench compensation_room] {msg}", file=sys.stderr, flush=True)


async def _rig_run(room, slots: list[str], workdir: Path, args, content_size, points, *, baseline: bool) -> dict:
    rig = make_rig(workdir, room, slots, content_size=content_size)
    driver = RoomDriver(room, rig)
    out: dict = {"projectors": len(slots)}
    t = time.perf_counter()
    cal = await driver.run("calibrate", {"mode": "multiplexed", "table_points": points_doc(points), "settle_s": 0.0})
    out["calibration"] = {"captures": cal["captures"], "wall_s": round(time.perf_counter() - t, 2)}
    _log(f"N={len(slots)}: calibrated ({cal['captures']} captures)")
    c0 = driver.captures
    t = time.perf_counter()
    resp = await driver.run("response", {"settle_s": 0.0, "frames": args.response_frames})
    gam = {s: float(np.max(np.abs(np.asarray(d["gamma"]) - room.truth.projector(s).gamma))) for s, d in resp["slots"].items()}
    curve = {}
    for s in resp["slots"]:
        doc = json.loads((rig.path / "compensation" / "responses" / f"{s}.json").read_text())["response"]
        lv, cv = np.asarray(doc["levels"]), np.asarray(doc["curve"])
        curve[s] = float(np.abs(cv - lv[None, :] ** room.truth.projector(s).gamma[:, None]).max())
    out["response"] = {"captures": driver.captures - c0, "wall_s": round(time.perf_counter() - t, 2),
                       "gamma_error_max": round(max(gam.values()), 4),
                       "curve_error_max": round(max(curve.values()), 4),
                       "curve_error_median": round(float(np.median(list(curve.values()))), 4),
                       "linearity": resp["linearity"], "brightness": resp["brightness"]}
    _log(f"N={len(slots)}: responses ({driver.captures - c0} captures, normalised curve error <= "
         f"{max(curve.values()):.4f}, linearity max error {resp['linearity']['max_error']})")
    c0 = driver.captures
    t = time.perf_counter()
    tr = await driver.run("transport", {"settle_s": 0.0, "radius": args.radius, "frames": args.frames})
    wall = time.perf_counter() - t
    L, _ = load_transport(rig.path / "compensation" / "transport.npz")
    parts = truth_transport_parts(room.truth.transport, lambda s: room.truth.projector(s).black, rig, slots)
    truth = sp.csr_matrix(sum(parts.values()), dtype=np.float32)
    out["transport"] = {"captures": driver.captures - c0, "wall_s": round(wall, 2), "spacing": tr["spacing"],
                        "radius": tr["radius"], "nnz": tr["nnz"], "relative_error": round(transport_error(L, truth), 5)}
    _log(f"N={len(slots)}: transport ({out['transport']['captures']} captures, error {out['transport']['relative_error']})")
    ridge = {} if args.regularization is None else {"regularization": args.regularization}
    params = {"image": encode_image_array(demo_image(content_size), "astronaut.png"), "evaluate": True,
              "settle_s": 0.0, "eval_frames": args.eval_frames, "max_iter": args.max_iter, "radius": args.radius,
              "frames": args.frames, **ridge}
    if baseline:
        params.update(baseline=True, baseline_frames=args.baseline_frames or args.frames,
                      baseline_exposure=args.baseline_exposure or float(len(slots)))
    c0 = driver.captures
    t = time.perf_counter()
    res = await driver.run("compensate", params)
    out["compensate"] = {k: res[k] for k in ("solve", "target_level", "target_level_from", "quality", "baseline",
                                             "baseline_over_ours_seconds") if k in res}
    out["compensate"]["captures"] = driver.captures - c0
    out["compensate"]["wall_s"] = round(time.perf_counter() - t, 2)
    out["compensate"]["solve"]["ms_per_iteration"] = round(1000 * res["solve"]["seconds"] / max(res["solve"]["iterations"], 1), 3)
    if baseline:
        errs = []
        truths = {}
        for s in slots:
            Li, _ = load_transport(rig.path / "compensation" / "baseline" / f"{s}.npz")
            truths[s] = sp.csr_matrix(parts[s], dtype=np.float32)
            errs.append(transport_error(Li, truths[s]))
        out["compensate"]["baseline"]["relative_error_mean"] = round(float(np.mean(errs)), 5)
        _log(f"N={len(slots)}: oracle solves (the room's true transport)")
        out["compensate"]["oracle"] = await asyncio.to_thread(_oracle, rig, res, truth, truths, content_size,
                                                            max_iter=args.max_iter)
    if args.video_frames > 0:
        wide = demo_image((content_size[0] + args.video_frames, content_size[1]))
        frames = [encode_image_array(np.ascontiguousarray(wide[:, k:k + content_size[0]]), f"f{k:03d}.png")
                  for k in range(args.video_frames)]
        keys = ("frames", "iterations_per_frame", "motion", "motion_share_mean", "ms_first_frame", "ms_per_frame_mean",
                "ms_per_frame_median", "ms_per_frame_max", "objective_mean")
        for name, motion in (("sequence", args.video_motion), ("sequence_still", "off")):
            if name == "sequence_still" and motion == args.video_motion:
                continue
            seq = await driver.run("compensate_sequence", {"frames": frames, "iterations": args.video_iterations,
                                                           "play": False, "motion": motion, **ridge})
            out[name] = {k: seq[k] for k in keys if k in seq}
            out[name]["clip"] = "the picture slides 1 content px per frame"
            _log(f"N={len(slots)}: sequence, motion {motion}: {seq['ms_per_frame_mean']} ms per frame, objective "
                 f"{seq['objective_mean']:.4g}")
    out["rig_dir"] = str(rig.path)
    return out


def _oracle(rig, res: dict, truth: sp.spmatrix, truths: dict, content_size, *, max_iter: int) -> dict:
    """Both methods solved with the room's true transport, scored through it (no camera): what each could
    reach with perfect measurements, at the same target, ridge weight and iteration budget."""
    _, meta = load_transport(rig.path / "compensation" / "transport.npz")
    H = np.asarray(meta["content_to_camera"])
    cam = (meta["camera_size"][1], meta["camera_size"][0])
    cw, ch = content_size
    content = prepare_image(demo_image(content_size), content_size)
    T = camera_target(content, H, cam)
    s = np.float32(res["target_level"])
    target = T * s
    region = inscribed_region(H, content_size, cam, margin=int(meta["radius"]) + 2)
    mu = res["solve"]["regularization"]
    flat = content.reshape(-1, 3)

    def score(x_or_light):
        c = np.asarray(x_or_light, np.float32).reshape(*cam, 3) / s
        return quality(T[region], c[region]).as_dict()

    def ridge_solve(L, goal):
        p = RidgeProblem(L, mu)
        a = best_scale(p.data.matvec(flat), goal.reshape(-1, 3))
        start = np.clip(content * np.float32(a), 0, 1)
        return solve(p.op, p.target(goal, start), x0=start, content_shape=(ch, cw), max_iter=max_iter).x, start

    ours, none = ridge_solve(truth, target)
    share = target / np.float32(len(truths))
    light = sum(Li @ ridge_solve(Li, share)[0].reshape(-1, 3) for Li in truths.values())
    return {"none": score(truth @ none.reshape(-1, 3)), "ours": score(truth @ ours.reshape(-1, 3)),
            "baseline": score(light),
            "note": "solved with the true transport, scored through it: the methods' ceilings in this room"}


def run(args: argparse.Namespace) -> int:
    cw, ch = args.content_size
    t0 = time.perf_counter()
    room = Room(reference_scene(projector_scale=args.projector_scale, camera_scale=args.camera_scale, seed=args.seed,
                                aperture=args.aperture), seed=args.seed, noise=not args.no_noise)
    points = table_points_from_truth(room, click_noise_px=0.3, seed=args.seed)
    doc: dict = {"benchmark": "compensation_room", "machine": machine(),
                 "parameters": {**{k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()
                                   if not k.startswith("_") and k not in ("command", "bench")},
                                "projector_size": list(room.projector_size("r0c0")), "camera_size": list(room.camera_size(0))}}
    with tempfile.TemporaryDirectory(prefix="bench-compensation-room-") as tmp:
        rigs = {}
        rigs["25"] = asyncio.run(_rig_run(room, list(SUBSETS["P25"]), Path(tmp) / "p25", args, (cw, ch), points,
                                          baseline=not args.no_baseline))
        if not args.single:
            rigs["1"] = asyncio.run(_rig_run(room, ["r2c2"], Path(tmp) / "p1", args, (cw, ch), points, baseline=False))
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            src = Path(rigs["25"]["rig_dir"]) / "compensation"
            for f in ("quality.png", "quality.json", "result.json", "response.json", "transport.json"):
                if (src / f).exists():
                    shutil.copy(src / f, args.out / f)
        for r in rigs.values():
            r.pop("rig_dir", None)
    doc["rigs"] = rigs
    q = rigs["25"]["compensate"]["quality"]
    targets: dict = {"quality_order": {
        "none_psnr": q["none"]["psnr"], "ours_psnr": q["ours"]["psnr"],
        "ours_minus_none_db": q["ordering"]["ours_minus_none_db"],
    }}
    if "baseline" in q:
        d = q["ordering"]
        targets["quality_order"].update(baseline_psnr=q["baseline"]["psnr"],
                                        ours_minus_baseline_db=d["ours_minus_baseline_db"],
                                        baseline_minus_none_db=d["baseline_minus_none_db"],
                                        met=d["ours_minus_baseline_db"] >= -0.05 and d["baseline_minus_none_db"] > 0.3
                                        and d["ours_minus_none_db"] > 0.3)
        targets["baseline_25_over_ours_25_solve"] = rigs["25"]["compensate"].get("baseline_over_ours_seconds")
    oracle = rigs["25"]["compensate"].get("oracle")
    if oracle:
        targets["quality_order_oracle"] = {k: oracle[k]["psnr"] for k in ("none", "baseline", "ours")}
    if "1" in rigs:
        s25, s1 = rigs["25"]["compensate"]["solve"], rigs["1"]["compensate"]["solve"]
        targets["ours_time_25_over_1"] = round(s25["seconds"] / max(s1["seconds"], 1e-9), 3)
        targets["ours_time_per_iteration_25_over_1"] = round(s25["ms_per_iteration"] / max(s1["ms_per_iteration"], 1e-9), 3)
        targets["ours_iterations_25_vs_1"] = [s25["iterations"], s1["iterations"]]
        targets["transport_captures_25_vs_1"] = [rigs["25"]["transport"]["captures"], rigs["1"]["transport"]["captures"]]
    doc["targets"] = targets
    doc["wall_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(doc, indent=2, default=float))
    return 0
