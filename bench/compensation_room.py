"""`shadowless bench compensation_room`: blur compensation measured in the virtual room.

The coordinator's jobs (``calibrate``, ``response``, ``transport``, ``compensate``) run
in-process against :class:`sim.room.Room` through :class:`RoomCompensationContext`, which
renders what every node would output (the node's warp, gain and LUT, computed by
:func:`coordinator.compensation.job.projector_frame`) into the room, so the figures measure
the method, not gRPC or node processes. Reported: captures and time of each stage, the
fitted response against the room's gamma, the measured ``L`` against the room's
ground-truth transport (relative Frobenius error), solve times of ours for a 1- and a
25-projector rig and of the per-projector baseline, and PSNR/SSIM of the image captured
without compensation, with the baseline and with ours, plus the side-by-side picture.

The baseline's matrices ``L_i`` are measured one projector at a time; a projector alone
gives the camera 1/N of the light, so by default its captures use an N times longer
exposure (``--baseline-exposure``; the room's camera can), so each ``L_i`` is measured at
the signal level ``L`` is.

This module is also the test kit of ``tests/coordinator/compensation/test_job_*``: the
adapter and the ground-truth transport (:func:`truth_transport`). It may import ``sim``;
the coordinator never does.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.sparse as sp

from bench.calibration import RoomJobContext, make_rig, table_points_from_truth


# ---------------------------------------------------------------------- the test kit
class _RoomCoordinator:
    """The two coordinator calls the compensation jobs make: ``show`` (a still, persisted) and ``play``."""

    def __init__(self, ctx: "RoomCompensationContext"):
        self.ctx = ctx
        self.shown = None
        self.played: list = []

    def show(self, content, *, persist: bool = False, **_):
        if persist:
            self.ctx.rig.set_content(content)
        self.ctx.render_content(content.image)
        self.shown = content
        return content

    async def play(self, frames, settings):
        from protos import control_pb2

        t0 = time.monotonic()
        count = len(frames) * (settings.loops + 1)
        for i in range(count):
            self.ctx.render_content(frames[i % len(frames)].image)
        self.played = list(frames)
        return control_pb2.PlayReply(frames_sent=count, frames_shown=count, nodes=len(self.ctx.live_slots()),
                                     wall_s=time.monotonic() - t0)


class RoomCompensationContext(RoomJobContext):
    """The JobContext calls the compensation jobs make, served by an in-process room.

    Content shown through poses is rendered as a node does it (bilinear warp, gain, LUT,
    ``round(255 v)``), with each slot's stored pose, LUT and gain; ``set_slot`` persists
    in the rig like the coordinator. ``capture(index, exposure=)`` scales the camera's
    exposure (relative to the room camera's own). Heavy work runs on worker threads, as
    :meth:`coordinator.jobs.JobContext.compute` does.
    """

    def __init__(self, room, rig, **kw):
        super().__init__(room, rig, **kw)
        self.coordinator = _RoomCoordinator(self)
        self.content_shows = 0

    def render_content(self, image: np.ndarray | None, *, apply_lut: bool = True) -> None:
        from coordinator.compensation.job import projector_frame

        cw, ch = self.rig.config.content_width, self.rig.config.content_height
        img = None if image is None else np.asarray(image)
        if img is not None and img.shape[:2] != (ch, cw):
            raise ValueError(f"content is {img.shape[1]}x{img.shape[0]}, the rig's is {cw}x{ch}")
        for s in self.live_slots():
            st = self.rig.slot(s)
            if img is None or st.pose is None:
                frame = np.zeros((st.height, st.width, 3), np.uint8)
            else:
                frame = projector_frame(img, st.pose.matrix, (st.width, st.height), lut=st.lut, gain=st.gain,
                                        apply=apply_lut)
            self.room.set_frame(s, frame)

    async def show_content(self, image, *, apply_lut: bool = True, settle_s: float = 0.05) -> None:
        await asyncio.to_thread(self.render_content, image, apply_lut=apply_lut)
        self.content_shows += 1

    async def capture(self, index: int = 0, *, exposure: float | None = None) -> np.ndarray:
        self.captures += 1
        base = self.exposure if self.exposure is not None else self.room.truth.camera(index).exposure
        e = base * (1.0 if exposure is None else float(exposure))
        return await asyncio.to_thread(self.room.capture, index, exposure=e)

    async def compute(self, fn, *args, **kwargs):
        return await asyncio.to_thread(fn, *args, **kwargs)

    def set_slot(self, slot: str, **changes) -> None:
        self.rig.update_slot(slot, **changes)


def bilinear_warp_matrix(pose: np.ndarray, projector_size: tuple[int, int], content_size: tuple[int, int]) -> sp.csr_matrix:
    """The node's content lookup as a matrix: ``(w*h, W*H)`` CSR float64, projector px x content px.

    Row ``v * w + u`` holds the bilinear weights of the four content texels around
    ``pose^-1 (u, v)`` (texels outside the content weigh 0), exactly the float arithmetic of
    ``node/render/pipeline.glsl``.
    """
    w, h = projector_size
    cw, ch = content_size
    v, u = np.mgrid[0:h, 0:w]
    q = np.linalg.inv(np.asarray(pose, np.float64)) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q[0] / q[2], q[1] / q[2]
    ok_w = (q[2] > 0) & np.isfinite(x) & np.isfinite(y)
    x = np.where(ok_w, x, -10.0)
    y = np.where(ok_w, y, -10.0)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    rows, cols, vals = [], [], []
    for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        X, Y = x0 + dx, y0 + dy
        ok = ok_w & (X >= 0) & (X < cw) & (Y >= 0) & (Y < ch) & (wt > 0)
        rows.append(np.flatnonzero(ok))
        cols.append(Y[ok] * cw + X[ok])
        vals.append(wt[ok])
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
    cw, ch = rig.config.content_width, rig.config.content_height
    total = None
    for s in slots:
        st = rig.slot(s)
        B = bilinear_warp_matrix(st.pose.matrix, (st.width, st.height), (cw, ch))
        part = (sp.csr_matrix(transport_of(s), dtype=np.float64) @ B) * (st.gain * float(np.mean(1 - black_of(s))) * exposure)
        total = part if total is None else total + part
    return sp.csr_matrix(total, dtype=np.float32)


def points_doc(points) -> dict:
    """Known table points as the calibration job's inline points document."""
    return {"frame": "world", "points": [{"xyz": [float(v) for v in x], "pixel": [float(v) for v in p], "camera": 0}
                                        for x, p in zip(points[0].xyz, points[0].pixels)]}


def demo_image(size: tuple[int, int]) -> np.ndarray:
    """scikit-image's astronaut, centre-cropped to ``size`` (w, h)'s aspect and resized: (h, w, 3) uint8."""
    import cv2
    from skimage import data

    img = data.astronaut()
    w, h = size
    ih, iw = img.shape[:2]
    if iw / ih > w / h:
        cw = round(ih * w / h)
        img = img[:, (iw - cw) // 2:(iw - cw) // 2 + cw]
    else:
        cht = round(iw * h / w)
        img = img[(ih - cht) // 2:(ih - cht) // 2 + cht]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def image_param(image: np.ndarray, name: str = "image.png") -> dict:
    """An in-memory image as the ``image`` job parameter (PNG bytes, compressed, base64)."""
    import base64
    import zlib

    import cv2

    a = np.asarray(image)
    if a.dtype == np.float32:
        import io

        buf = io.BytesIO()
        np.save(buf, a, allow_pickle=False)
        raw, name = buf.getvalue(), name.rsplit(".", 1)[0] + ".npy"
    else:
        ok, png = cv2.imencode(".png", cv2.cvtColor(a, cv2.COLOR_RGB2BGR) if a.ndim == 3 else a)
        if not ok:
            raise ValueError("cannot encode the image")
        raw = png.tobytes()
    return {"name": name, "data": base64.b64encode(zlib.compress(raw, 6)).decode("ascii")}


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
    parser.add_argument("--content-size", default="300x150", metavar="WxH",
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
    parser.add_argument("--out", type=Path, default=None, help="copy the side-by-side picture and the rig's JSON here")


def _log(msg: str) -> None:
    print(f"[bench compensation_room] {msg}", file=sys.stderr, flush=True)


async def _rig_run(room, slots: list[str], workdir: Path, args, content_size, points, *, baseline: bool) -> dict:
    from coordinator.calibration.job import calibrate
    from coordinator.compensation.job import compensate, measure_response, measure_transport
    from coordinator.compensation import load_transport
    from coordinator.compensation.transport import transport_error

    rig = make_rig(workdir, room, slots, content_size=content_size)
    ctx = RoomCompensationContext(room, rig)
    out: dict = {"projectors": len(slots)}
    t = time.perf_counter()
    cal = await calibrate(ctx, {"mode": "multiplexed", "table_points": points_doc(points), "settle_s": 0.0})
    out["calibration"] = {"captures": cal["captures"], "wall_s": round(time.perf_counter() - t, 2)}
    _log(f"N={len(slots)}: calibrated ({cal['captures']} captures)")
    c0 = ctx.captures
    t = time.perf_counter()
    resp = await measure_response(ctx, {"settle_s": 0.0, "frames": args.response_frames})
    gam = {s: float(np.max(np.abs(np.asarray(d["gamma"]) - room.truth.projector(s).gamma))) for s, d in resp["slots"].items()}
    curve = {}
    for s in resp["slots"]:
        doc = json.loads((rig.path / "compensation" / "responses" / f"{s}.json").read_text())["response"]
        lv, cv = np.asarray(doc["levels"]), np.asarray(doc["curve"])
        curve[s] = float(np.abs(cv - lv[None, :] ** room.truth.projector(s).gamma[:, None]).max())
    out["response"] = {"captures": ctx.captures - c0, "wall_s": round(time.perf_counter() - t, 2),
                       "gamma_error_max": round(max(gam.values()), 4),
                       "curve_error_max": round(max(curve.values()), 4),
                       "curve_error_median": round(float(np.median(list(curve.values()))), 4),
                       "linearity": resp["linearity"], "brightness": resp["brightness"]}
    _log(f"N={len(slots)}: responses ({ctx.captures - c0} captures, normalised curve error <= {max(curve.values()):.4f}, "
         f"linearity max error {resp['linearity']['max_error']})")
    c0 = ctx.captures
    t = time.perf_counter()
    tr = await measure_transport(ctx, {"settle_s": 0.0, "radius": args.radius, "frames": args.frames})
    wall = time.perf_counter() - t
    L, _ = load_transport(rig.path / "compensation" / "transport.npz")
    truth = truth_transport(room.truth.transport, lambda s: room.truth.projector(s).black, rig, slots)
    out["transport"] = {"captures": ctx.captures - c0, "wall_s": round(wall, 2), "spacing": tr["spacing"],
                        "radius": tr["radius"], "nnz": tr["nnz"], "relative_error": round(transport_error(L, truth), 5)}
    _log(f"N={len(slots)}: transport ({out['transport']['captures']} captures, error {out['transport']['relative_error']})")
    ridge = {} if args.regularization is None else {"regularization": args.regularization}
    params = {"image": image_param(demo_image(content_size), "astronaut.png"), "evaluate": True, "settle_s": 0.0,
              "eval_frames": args.eval_frames, "max_iter": args.max_iter, "radius": args.radius, "frames": args.frames,
              **ridge}
    if baseline:
        params.update(baseline=True, baseline_frames=args.baseline_frames or args.frames,
                      baseline_exposure=args.baseline_exposure or float(len(slots)))
    c0 = ctx.captures
    t = time.perf_counter()
    res = await compensate(ctx, params)
    out["compensate"] = {k: res[k] for k in ("solve", "target_level", "target_level_from", "quality", "baseline",
                                             "baseline_over_ours_seconds") if k in res}
    out["compensate"]["captures"] = ctx.captures - c0
    out["compensate"]["wall_s"] = round(time.perf_counter() - t, 2)
    out["compensate"]["solve"]["ms_per_iteration"] = round(1000 * res["solve"]["seconds"] / max(res["solve"]["iterations"], 1), 3)
    if baseline:
        errs = []
        truths = {}
        for s in slots:
            Li, _ = load_transport(rig.path / "compensation" / "baseline" / f"{s}.npz")
            truths[s] = truth_transport(room.truth.transport, lambda k: room.truth.projector(k).black, rig, [s])
            errs.append(transport_error(Li, truths[s]))
        out["compensate"]["baseline"]["relative_error_mean"] = round(float(np.mean(errs)), 5)
        _log(f"N={len(slots)}: oracle solves (the room's true transport)")
        out["compensate"]["oracle"] = await asyncio.to_thread(_oracle, rig, res, truth, truths, content_size)
    if args.video_frames > 0:
        from coordinator.compensation.job import compensate_sequence

        wide = demo_image((content_size[0] + args.video_frames, content_size[1]))
        frames = [image_param(np.ascontiguousarray(wide[:, k:k + content_size[0]]), f"f{k:03d}.png")
                  for k in range(args.video_frames)]
        seq = await compensate_sequence(ctx, {"frames": frames, "iterations": args.video_iterations, "play": False,
                                              **ridge})
        out["sequence"] = {k: seq[k] for k in ("frames", "iterations_per_frame", "ms_first_frame", "ms_per_frame_mean",
                                               "ms_per_frame_median", "ms_per_frame_max")}
        out["sequence"]["clip"] = "the picture slides 1 content px per frame"
    out["rig_dir"] = str(rig.path)
    return out


def _oracle(rig, res: dict, truth: sp.spmatrix, truths: dict, content_size) -> dict:
    """Both methods solved with the room's true transport, scored through it (no camera): what each could
    reach with perfect measurements, at the same target, ridge weight and iteration budget."""
    from coordinator.compensation import load_transport, quality, solve
    from coordinator.compensation.job import RidgeProblem, best_scale, camera_target, inscribed_region, prepare_image

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
        return solve(p.op, p.target(goal, start), x0=start, content_shape=(ch, cw), max_iter=300).x, start

    ours, none = ridge_solve(truth, target)
    share = target / np.float32(len(truths))
    light = sum(Li @ ridge_solve(Li, share)[0].reshape(-1, 3) for Li in truths.values())
    return {"none": score(truth @ none.reshape(-1, 3)), "ours": score(truth @ ours.reshape(-1, 3)),
            "baseline": score(light),
            "note": "solved with the true transport, scored through it: the methods' ceilings in this room"}


def run(args: argparse.Namespace) -> int:
    import shutil

    from bench.machine import machine
    from sim.room import Room
    from sim.scene import SUBSETS, reference_scene

    cw, ch = (int(v) for v in args.content_size.lower().split("x"))
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
