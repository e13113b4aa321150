"""`shadowless demo` (what `make demo` runs): the whole rig in the virtual room.

It starts the room (the paper's 5x5 ceiling array over a 1200x600 mm table, plus
the single bright projector "p1" at the centre position), a coordinator that
captures from the room's camera, and one node process per projector whose
frames go to the room. It aligns the projectors (calibration, or the room's
ground-truth poses with ``--poses truth``), shows an image on every projector,
puts a hand 0.2 m above the table, and compares the single bright projector (P1)
with the 25-projector synthetic aperture (P25): side-by-side pictures like the
paper's teaser, light-drop maps and a short report, written to ``--out``. Then it
compensates the 25 projectors' blur: their luminance responses, the rig's summed light
transport (every projector at once) and one solve, with the image captured without and
with compensation (PSNR/SSIM, a side-by-side picture); ``--no-compensate`` skips it.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sim.drop_figures import drop_statistics
from coordinator.compensation.image_param import encode_image_param
from rigctl.job_command import ProgressView, run_job
from protos import cli_types
from protos.spaces import content_to_table
from protos.wording import count
from shadowless import exit_cleanup
from shadowless.demo_figures import light_drop_figure, teaser_figure
from shadowless.hold import console_lines, hold
from shadowless.local import LocalRig, free_port
from shadowless.process_stop import stop_process
from sim.link import RoomClient
from sim.hand import Hand
from sim.scene import SUBSETS


def configure(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n")[0].replace("`shadowless demo` (what `make demo` runs): ", "").strip()
    p.epilog = ("writes to OUT: teaser.png (P1 vs P25, without and with the hand), light_drop.png (on the table, "
                "in mm), compensation.png (target, without and with blur compensation, a zoomed crop and the "
                "difference to the target), report.json and report.md, "
                "and rig/ (the rig directory and every process's log)")
    p.add_argument("--out", default="results/demo", help="results folder (default results/demo)")
    p.add_argument("--image", help="image to project (default: scikit-image's astronaut)")
    p.add_argument("--poses", choices=["calibrate", "truth"], default="calibrate",
                   help="align by calibrating through the camera (default) or take the room's ground truth")
    p.add_argument("--hand", type=cli_types.pair, default="320,120", metavar="X,Y", help="hand position on the table in mm (default 320,120)")
    p.add_argument("--hand-height", type=cli_types.number(0, 2000), default=200.0, help="height of the hand above the table (default 200 mm)")
    p.add_argument("--content-size", type=cli_types.size, default="600x300", metavar="WxH",
                   help="shared image size in content px over the 1200x600 mm table (default 600x300: 2 mm/px)")
    p.add_argument("--no-compensate", dest="compensate", action="store_false",
                   help="skip the blur-compensation stage (responses, light transport, solve; about a minute)")
    p.add_argument("--serve", action="store_true",
                   help="then keep the room, the calibrated rig and its operator console up until Ctrl-C (or "
                        "SIGTERM), to try the console on it; every process stops at the end, the results stay")


def _say(msg: str) -> None:
    print(f"[demo {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def table_region(camera_p: np.ndarray, cam_size: tuple[int, int], table_mm=(1200.0, 600.0)) -> tuple[np.ndarray, np.ndarray]:
    """Where the table is in the camera image, and the table area (mm^2) each pixel covers.

    Returns ``(on_table (H, W) bool, px_area (H, W) float64)`` from the camera's
    3x4 matrix: the table plane z = 0 maps to the image by ``P[:, [0, 1, 3]]``.
    """
    W, H = cam_size
    h_tc = camera_p[:, [0, 1, 3]]
    tw, th = table_mm
    corners = np.array([[-tw / 2, -th / 2, 1], [tw / 2, -th / 2, 1], [tw / 2, th / 2, 1], [-tw / 2, th / 2, 1]]).T
    px = h_tc @ corners
    px = (px[:2] / px[2]).T
    on = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(on, np.round(px * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    # area of a pixel on the table = 1 / |det J| of the table->camera map, J at each pixel
    h_ct = np.linalg.inv(h_tc)
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    q = h_ct @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    x, y, w = q
    a, b, c = h_ct[0]
    d, e, f = h_ct[1]
    g, hh, _ = h_ct[2]
    # Jacobian of (x/w, y/w) with respect to pixel (u, v)
    j11 = (a * w - x * g) / w**2
    j12 = (b * w - x * hh) / w**2
    j21 = (d * w - y * g) / w**2
    j22 = (e * w - y * hh) / w**2
    area = np.abs(j11 * j22 - j12 * j21).reshape(H, W)
    return on.astype(bool), area


def table_points(camera_p: np.ndarray, *, noise_px: float = 0.3, seed: int = 0) -> list[list[float]]:
    """Known points for the table->camera mapping: marks on the table (world mm) and where an operator
    clicked them in the camera image (the truth plus click noise). ``[[x_mm, y_mm, u_px, v_px], ...]``"""
    rng = np.random.default_rng(seed)
    pts = []
    for x in (-560.0, -280.0, 0.0, 280.0, 560.0):
        for y in (-260.0, 0.0, 260.0):
            u = camera_p @ np.array([x, y, 0.0, 1.0])
            uv = u[:2] / u[2] + rng.normal(0, noise_px, 2)
            pts.append([x, y, float(uv[0]), float(uv[1])])
    return pts


def default_image() -> np.ndarray:
    from skimage import data

    return data.astronaut()


def read_demo_image(path: str) -> np.ndarray:
    """An operator's picture for the demo as (H, W, 3) uint8 RGB, read through the coordinator's
    one decoder (any format it reads, its declared size checked first; 16-bit and float 0..1
    scaled to 8 bits, grey repeated, alpha dropped). SystemExit with one line when it is refused."""
    from rigctl.client import OperatorError
    from rigctl.commands import read_image

    try:
        img = read_image(path)
    except OperatorError as exc:
        raise SystemExit(f"--image {exc}") from None
    if img.dtype == np.uint16:
        img = np.round(img / 257.0).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.round(np.asarray(img, np.float32) * 255.0).astype(np.uint8)
    if img.ndim == 2:
        img = img[:, :, None]
    return np.ascontiguousarray(np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img[:, :, :3])


def fit_image(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Centre-crop to the content aspect ratio, then resize to ``size`` (w, h)."""
    w, h = size
    ih, iw = img.shape[:2]
    target = w / h
    if iw / ih > target:
        cw = int(round(ih * target))
        img = img[:, (iw - cw) // 2: (iw - cw) // 2 + cw]
    else:
        ch = int(round(iw / target))
        img = img[(ih - ch) // 2: (ih - ch) // 2 + ch]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


async def _demo(args) -> int:

    t_start = time.monotonic()
    picture = read_demo_image(args.image) if args.image else None   # refused now, not after calibrating
    out = Path(args.out)
    work = out / "rig"
    if work.exists():
        shutil.rmtree(work)
    out.mkdir(parents=True, exist_ok=True)
    (work / "logs").mkdir(parents=True, exist_ok=True)
    cw, ch = args.content_size
    hx, hy = args.hand

    room_port = free_port()
    room_log = open(work / "logs" / "room.log", "wb")
    room_proc = subprocess.Popen([sys.executable, "-m", "shadowless", "room", "--host", "127.0.0.1", "--port", str(room_port)],
                                 stdout=room_log, stderr=subprocess.STDOUT, start_new_session=True)
    exit_cleanup.register(room_proc.terminate)   # stopped even if the demo itself is terminated
    report: dict = {"poses": args.poses, "hand_mm": [hx, hy], "hand_height_mm": args.hand_height,
                    "content_size": [cw, ch]}
    try:
        room = RoomClient(f"127.0.0.1:{room_port}")
        room.wait_ready(60)
        desc = room.describe()
        slots = [p.slot for p in desc.projectors]
        cam = room.camera_truth(0)
        cam_p = np.array(cam.p).reshape(3, 4)
        cam_size = (cam.width, cam.height)
        _say(f"virtual room on 127.0.0.1:{room_port}: {count(len(slots), 'projector')}, camera {cam.width}x{cam.height}")

        size = room.projector_size(slots[0])
        rig = LocalRig(slots, work, output_size=size, content_size=(cw, ch), node_output=f"room://127.0.0.1:{room_port}",
                       mdns=True, rig_name="demo", latency_ms=80.0, console=True,
                       coordinator_args=["--camera", f"room://127.0.0.1:{room_port}"])
        with rig:
            _say(f"coordinator on 127.0.0.1:{rig.port}; starting {count(len(slots), 'node process', 'node processes')} "
                 "(one per projector)")
            _say(f"operator console: {rig.console_url()} (log in with the token in {rig.rig_dir / 'token'})")
            async with await rig.client(timeout=60) as c:
                await rig.wait_live(c, timeout=300)
                report["startup_s"] = round(time.monotonic() - t_start, 1)
                _say(f"{count(len(slots), 'node')} live after {report['startup_s']} s")

                t0 = time.monotonic()
                if args.poses == "truth":
                    _say("NOTE: poses are taken from the room's ground truth, not calibrated (--poses truth)")
                    c2t = content_to_table((cw, ch), (1200.0, 600.0))
                    for slot in slots:
                        p = np.array(room.projector_truth(slot).p).reshape(3, 4)
                        h = p[:, [0, 1, 3]] @ c2t
                        await c.configure(slot, homography=h / h[2, 2])
                    if args.compensate:   # compensation needs the table -> camera mapping (no projector patterns)
                        await run_job(c, "calibrate", {"table_only": True, "table_points": table_points(cam_p)})
                else:
                    # The 25-projector array and the single bright unit are two rigs in one room:
                    # switch each on in turn (as an operator would) and calibrate it.
                    report["calibration"] = {}
                    for name in ("P25", "P1"):
                        room.set_active(SUBSETS[name])
                        _say(f"calibrating {name} ({len(SUBSETS[name])} projector(s)) through the room's camera")
                        params = {"mode": "multiplexed", "table_points": table_points(cam_p), "force": True,
                                  "slots": SUBSETS[name]}
                        report["calibration"][name] = await run_job(c, "calibrate", params, view=ProgressView(sys.stdout))
                report["alignment_s"] = round(time.monotonic() - t0, 1)

                img = fit_image(picture if picture is not None else default_image(), (cw, ch))
                shown = await c.show(img, name=Path(args.image).name if args.image else "astronaut", persist=True)
                _say("showing the image on every projector")

                def capture():
                    cap = room.capture(0, not_before_rig_ns=shown.pts_ns, timeout_ms=20000)
                    return cap.image

                on, px_area = table_region(cam_p, cam_size)
                shots, drops = {}, {}
                for name in ("P1", "P25"):
                    room.set_active(SUBSETS[name])
                    room.set_occluders([])
                    shots[(name, False)] = capture()
                    room.set_occluders([Hand(position=(hx, hy), height=args.hand_height)])
                    shots[(name, True)] = capture()
                    drops[name] = room.light_drop(0)
                    report.setdefault("light_drop", {})[name] = drop_statistics(drops[name], on, px_area)
                room.set_occluders([])
                room.set_active(SUBSETS["P25"])
                _say("captured P1 and P25, without and with the hand")
                if args.compensate:
                    image_name = Path(args.image).stem if args.image else "astronaut"
                    report["compensation"] = await _compensate(c, img, work, SUBSETS["P25"], image_name)
                    _write_compensation_picture(rig.rig_dir / "compensation", out / "compensation.png")
                _write_results(args, out, report, shots, drops, cam_p, t_start)
                if args.serve:
                    await hold(console_lines(rig.console_url(), rig.rig_dir),
                               then=f"the room, the coordinator and every node stop; the results stay in {out}/")
    finally:
        exit_cleanup.unregister(room_proc.terminate)
        stop_process(room_proc)
        room_log.close()
    hint = serve_hint(args.serve)
    if hint:
        _say(hint)
    return 0


def serve_hint(served: bool) -> str | None:
    """What the demo says last: how to keep the rig up and try its console (None when it did, ``--serve``)."""
    return None if served else "to keep this rig up and try its operator console: shadowless demo --serve (Ctrl-C stops it)"


def _write_compensation_picture(cdir: Path, dest: Path) -> None:
    """compensation.png: the compensate job's own picture (``cdir/quality.png``: full size, the detail
    where the blur costs most enlarged, and the difference to the target on one colour scale, drawn by
    :func:`imaging.compensation.quality_figure.compensation_figure` from the job's float captures), the
    one the operator's console shows."""
    shutil.copy(cdir / "quality.png", dest)


def _write_results(args, out: Path, report: dict, shots: dict, drops: dict, camera_p: np.ndarray, t_start: float) -> None:
    """The pictures (teaser.png and its smaller teaser.jpg, light_drop.png) and the report (report.json,
    report.md, printed)."""
    hx, hy = args.hand
    # exposure: both setups are equally bright (p1 is the paper's high-luminance unit)
    teaser = teaser_figure(shots, args.hand_height)
    cv2.imwrite(str(out / "teaser.png"), teaser)
    # the README's copy (docs/teaser.jpg is this file): three quarters of the size, its captions still legible
    small = cv2.resize(teaser, None, fx=0.75, fy=0.75, interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(out / "teaser.jpg"), small, [cv2.IMWRITE_JPEG_QUALITY, 85])
    heat, _ = light_drop_figure(drops, camera_p, hand_mm=(hx, hy), hand_height_mm=args.hand_height)
    cv2.imwrite(str(out / "light_drop.png"), heat)
    report["total_s"] = round(time.monotonic() - t_start, 1)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    lines = ["# shadowless demo", "",
             f"Poses: {'calibrated through the camera' if args.poses == 'calibrate' else 'ground truth of the room (not calibrated)'}.",
             f"Hand {args.hand_height:.0f} mm above the table at ({hx:.0f}, {hy:.0f}) mm.", "",
             "| setup | max light drop | mean drop (affected) | area below 50 % (mm²) | umbra ≥ 90 % (mm²) | transition (mm) |",
             "|---|---|---|---|---|---|"]
    for n, s in report["light_drop"].items():
        lines.append(f"| {n} | {s['max']:.0%} | {s['mean']:.0%} | {s['area_below_50_mm2']:.0f} | {s['umbra_mm2']:.0f} | "
                     f"{s['transition_mm'] if s['transition_mm'] is not None else '-'} |")
    comp = report.get("compensation")
    if comp:
        lines += ["", f"Blur compensation of the {comp['projectors']} projectors ({comp['response_captures']} response captures, "
                  f"{comp['transport_captures']} light-transport captures with every projector at once, solve "
                  f"{comp['solve_s']:.2f} s in {comp['iterations']} iterations), captured by the room's camera:", "",
                  "| | PSNR (dB) | SSIM |", "|---|---|---|",
                  f"| without compensation | {comp['none']['psnr']:.2f} | {comp['none']['ssim']:.3f} |",
                  f"| compensated | {comp['ours']['psnr']:.2f} | {comp['ours']['ssim']:.3f} |"]
    lines += ["", "Pictures: teaser.png (P1 vs P25, without and with the hand), light_drop.png (the light the hand takes "
              "from each point of the table, in mm)"
              + (", compensation.png (target, without, with compensation: full size, a zoomed crop and the "
                 "difference to the target)." if comp else "."),
              f"Run time: {report['total_s']} s (start-up {report['startup_s']} s, alignment {report['alignment_s']} s)."]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    _say(f"results in {out}/ ({report['total_s']} s)")


async def _compensate(c, img: np.ndarray, work: Path, slots: list[str], name: str) -> dict:
    """Blur compensation of the 25-projector rig: responses, summed light transport, one solve, evaluated
    (``name``: the image's, without extension, as the job's picture calls it)."""
    t0 = time.monotonic()
    view = ProgressView(sys.stdout)
    _say(f"blur compensation of {len(slots)} projectors: luminance responses (grey patches, one projector at a time)")
    resp = await run_job(c, "response", {"slots": slots}, view=view)
    _say("light transport: dot grids shown by every projector at once")
    tr = await run_job(c, "transport", {"slots": slots}, view=view)
    path = work / f"{name}.png"
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    _say("solving and capturing the image without and with compensation")
    res = await run_job(c, "compensate", {"image": encode_image_param(path), "slots": slots, "evaluate": True},
                        view=view)
    q = res["quality"]
    return {"projectors": len(slots), "response_captures": resp["captures"],
            "linearity_max_error": resp["linearity"]["max_error"], "transport_captures": tr["captures"],
            "transport_nnz": tr["nnz"], "solve_s": res["solve"]["seconds"], "iterations": res["solve"]["iterations"],
            "none": q["none"], "ours": q["ours"], "region": q.get("region"), "picture": q.get("picture_shows"),
            "total_s": round(time.monotonic() - t0, 1)}


def run(args: argparse.Namespace) -> int:
    return asyncio.run(_demo(args))
