"""`shadowless response`, `shadowless transport` and `shadowless compensate`: the blur-compensation
jobs, run on the coordinator with a progress bar per stage.

Images named on the command line are read here and sent with the job, so the coordinator may
run on another machine; results (LUTs, the light transport, the compensated content, the
quality picture) are stored in the rig directory on the coordinator's machine.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from coordinator.jobclient import run_job_command
from coordinator.operator import add_connection_args

EXAMPLES = """\
a planar rig, after `shadowless calibrate`:
  shadowless response   --rig-dir rigs/table                  # LUTs + brightness + linearity check
  shadowless transport  --rig-dir rigs/table                  # L: S*S captures, all projectors at once
  shadowless compensate --rig-dir rigs/table picture.png      # solve, store, show on every projector
  shadowless compensate --rig-dir rigs/table picture.png --evaluate --baseline   # PSNR/SSIM, picture
  shadowless play --rig-dir rigs/table frames/ --compensate   # a sequence, frame by frame

The response of a projector P1 as the brightness reference for the others:
  shadowless response --rig-dir rigs/table --slots p1
  shadowless response --rig-dir rigs/table --slots r0c0,...,r4c4 --reference p1
An interrupted run resumes (responses and baseline matrices are kept per projector, L is reused
while the poses, LUTs and gains it was measured with are unchanged); --force measures again.
"""


def _slots(text: str) -> list[str]:
    out = [s.strip() for s in text.split(",") if s.strip()]
    if not out:
        raise argparse.ArgumentTypeError("expected slot names, e.g. r0c0,r0c1")
    return out


def _grid(text: str) -> list[int]:
    try:
        r, c = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ROWSxCOLS, e.g. 4x4, got {text!r}") from None
    return [r, c]


def _reference(text: str) -> str | float:
    try:
        return float(text)
    except ValueError:
        return text


def _common(p: argparse.ArgumentParser) -> None:
    add_connection_args(p)
    c = p.add_argument_group("camera and captures")
    c.add_argument("--camera", action="append", metavar="SPEC",
                   help="camera(s) for this run: room://HOST:PORT, opencv:INDEX, ... (default: the coordinator's)")
    c.add_argument("--camera-index", type=int, metavar="I", help="which calibrated camera to use (default 0)")
    c.add_argument("--settle", type=float, metavar="S", help="wait after every swap before capturing (default 0.05 s)")
    p.add_argument("--force", action="store_true", help="measure again instead of reusing stored results")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _common_params(args: argparse.Namespace) -> dict:
    params: dict = {}
    if args.camera:
        params["cameras"] = list(args.camera)
    if args.camera_index is not None:
        params["camera"] = args.camera_index
    if args.settle is not None:
        params["settle_s"] = args.settle
    if args.force:
        params["force"] = True
    return params


def _transport_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("light transport")
    g.add_argument("--radius", type=int, metavar="R", help="PSF recovery radius in camera pixels (default 2)")
    g.add_argument("--spacing", type=int, metavar="S", help="dot-grid spacing in content pixels (default: the "
                   "smallest that separates the windows; S*S captures)")
    g.add_argument("--frames", type=int, metavar="F", help="captures averaged per pattern (default 1)")
    g.add_argument("--baseline-frames", type=int, metavar="F", help="captures averaged per pattern for the per-projector "
                   "baseline (default: --frames)")


def _transport_params(args: argparse.Namespace) -> dict:
    params: dict = {}
    for key, attr in (("radius", "radius"), ("spacing", "spacing"), ("frames", "frames"),
                      ("baseline_frames", "baseline_frames")):
        value = getattr(args, attr, None)
        if value is not None:
            params[key] = value
    return params


def _fmt(v, nd: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"


# ---------------------------------------------------------------- response
def configure_response(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Measure each projector's luminance response (grey levels shown by that projector alone), fit a\n"
        "monotone curve, store its inverse LUT (pushed to the node), match the rig's brightness to a\n"
        "reference with one uniform gain, and check that the rig's light after the LUTs is linear."
    )
    p.epilog = EXAMPLES
    _common(p)
    g = p.add_argument_group("what to measure")
    g.add_argument("--slots", type=_slots, metavar="A,B,...", help="only these projectors (default: every connected one)")
    g.add_argument("--mode", choices=["patches", "full"], help="patches (default: several grey levels per capture, "
                   "needs the calibration) or full (one uniform level per capture)")
    g.add_argument("--levels", type=int, metavar="K", help="grey levels from 0 to 1 (default 17)")
    g.add_argument("--grid", type=_grid, metavar="RxC", help="patches per frame (default 4x4)")
    g.add_argument("--reference", type=_reference, metavar="SLOT|LUMINANCE",
                   help="match the rig's white to this projector's (measured) or to a camera luminance above black")
    g.add_argument("--lut-entries", type=int, metavar="E", help="LUT entries (default 1024)")
    g.add_argument("--frames", type=int, metavar="F", help="captures averaged per pattern (default 1; raise it "
                   "when a projector alone is dim in the camera: its fitted curve carries the camera's noise)")


def response_params(args: argparse.Namespace) -> dict:
    params = _common_params(args)
    for key, attr in (("slots", "slots"), ("mode", "mode"), ("levels", "levels"), ("grid", "grid"),
                      ("reference", "reference"), ("lut_entries", "lut_entries"), ("frames", "frames")):
        value = getattr(args, attr, None)
        if value is not None:
            params[key] = value
    return params


def response_report(result: dict) -> str:
    lines = [f"luminance responses ({result.get('mode')} mode): {result.get('captures')} captures in "
             f"{_fmt(result.get('wall_s'), 1)} s"]
    lines.append(f"{'slot':<10} {'gamma r/g/b':>22} {'black':>9} {'white':>9}  note")
    for slot, d in result.get("slots", {}).items():
        gam = "/".join(f"{g:.3f}" for g in d["gamma"])
        lines.append(f"{slot:<10} {gam:>22} {_fmt(d['black'][0], 5):>9} {_fmt(d['peak'][0], 4):>9}  "
                     f"{'kept from an earlier run' if d.get('resumed') else ''}".rstrip())
    for slot, msg in result.get("failed", {}).items():
        lines.append(f"{slot:<10} failed: {msg}")
    b = result.get("brightness", {})
    if b:
        lines.append(f"brightness: reference {b['reference']}; gain {b['gain']:.4f}, headroom {b['headroom']:.3f}"
                     + ("" if b.get("reachable", True) else " (reference not reachable)"))
    lin = result.get("linearity", {})
    if lin:
        lines.append(f"linearity after the LUTs: max error {100 * lin['max_error']:.2f} % of full scale "
                     f"({'ok' if lin['linear'] else 'NOT linear'}, tolerance {100 * lin['tolerance']:.1f} %)")
    return "\n".join(lines)


def run_response(args: argparse.Namespace) -> int:
    return run_job_command(args, "response", response_params(args), report=response_report)


# ---------------------------------------------------------------- transport
def configure_transport(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Measure the rig's light transport L: every projector shows the same shifted dot-grid patterns at\n"
        "once (S*S captures, whatever the number of projectors); each content pixel's summed PSF is recovered\n"
        "within a radius and L is stored in the rig directory (compensation/transport.npz). --baseline also\n"
        "measures each projector alone (N*S*S captures), for the per-projector comparison only."
    )
    p.epilog = EXAMPLES
    _common(p)
    _transport_args(p)
    p.add_argument("--baseline", action="store_true", help="also measure each projector's L_i, one at a time")
    p.add_argument("--slots", type=_slots, metavar="A,B,...", help="projectors that must take part (default: every "
                   "connected one with a pose)")


def transport_params(args: argparse.Namespace) -> dict:
    params = {**_common_params(args), **_transport_params(args)}
    if args.baseline:
        params["baseline"] = True
    if args.slots:
        params["slots"] = args.slots
    return params


def transport_report(result: dict) -> str:
    lines = [f"light transport {'reused (unchanged rig)' if result.get('reused') else 'measured'}: "
             f"{result.get('captures')} captures ({result.get('patterns')} dot patterns, spacing {result.get('spacing')}, "
             f"radius {result.get('radius')}), {result.get('nnz')} non-zeros, {result.get('slots')} projectors",
             f"stored in the rig directory: {result.get('file')} ({result.get('date')})"]
    w = result.get("white")
    if w:
        lines.append(f"rig white inside the content: 2nd percentile {w['p2']}, median {w['median']} (camera units)")
    b = result.get("baseline")
    if b:
        lines.append(f"baseline: {len(b['slots'])} projectors, {b['captures']} captures this run "
                     f"({b['captures_per_projector']} per projector) in {_fmt(b['seconds'], 1)} s"
                     + (f"; left out (no light): {', '.join(b['excluded'])}" if b.get("excluded") else ""))
    return "\n".join(lines)


def run_transport(args: argparse.Namespace) -> int:
    return run_job_command(args, "transport", transport_params(args), report=transport_report)


# ---------------------------------------------------------------- compensate
def configure_compensate(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Compensate the rig's blur for an image: one bounded least-squares solve over the summed light\n"
        "transport (progress: iteration and objective); the result is stored as the rig's content and shown\n"
        "on every projector. --evaluate captures the image without compensation, with ours (and with\n"
        "--baseline, the per-projector method) and scores each against the target (PSNR, SSIM)."
    )
    p.epilog = EXAMPLES
    p.add_argument("image", help="image file (PNG/TIFF/JPEG, 8 or 16 bit, or .npy float32 in [0, 1])")
    _common(p)
    g = p.add_argument_group("solve")
    g.add_argument("--srgb", action="store_true", help="the image is sRGB-encoded (default: values are linear "
                   "luminance, as `shadowless show` shows them)")
    g.add_argument("--level", type=float, metavar="F", help="target white as a fraction of the rig's white "
                   "(2nd percentile over the content; default 0.9)")
    g.add_argument("--max-iter", type=int, metavar="N", help="iteration budget (default 300)")
    g.add_argument("--tol", type=float, metavar="T", help="relative objective decrease that stops (default 1e-5)")
    g.add_argument("--method", choices=["apg", "steepest", "lbfgsb"], help="solver (default apg)")
    g.add_argument("--regularization", type=float, metavar="MU", help="ridge weight towards the uncompensated image, "
                   "relative to ||L||^2 (default 0.02; 0 fits the measured L exactly, noise included)")
    g.add_argument("--no-show", action="store_true", help="solve and store figures only; leave the content as it is")
    g.add_argument("--no-measure", action="store_true", help="fail instead of measuring L when none is valid")
    e = p.add_argument_group("evaluation")
    e.add_argument("--evaluate", action="store_true", help="capture none / ours (/ baseline): PSNR, SSIM, "
                   "compensation/quality.png in the rig directory")
    e.add_argument("--baseline", action="store_true", help="also solve and show the per-projector baseline "
                   "(its L_i are measured when missing: N times the captures)")
    e.add_argument("--eval-frames", type=int, metavar="F", help="captures averaged per evaluated result (default 4)")
    _transport_args(p)


def compensate_params(args: argparse.Namespace) -> dict:
    from coordinator.compensation.job import encode_image_param

    f = Path(args.image)
    try:
        params: dict = {"image": encode_image_param(f)}
    except OSError as exc:
        raise SystemExit(f"shadowless compensate: cannot read {f}: {exc.strerror or exc}") from None
    params.update(_common_params(args))
    params.update(_transport_params(args))
    for key, attr in (("level", "level"), ("max_iter", "max_iter"), ("tol", "tol"), ("method", "method"),
                      ("eval_frames", "eval_frames"), ("regularization", "regularization")):
        value = getattr(args, attr, None)
        if value is not None:
            params[key] = value
    if args.srgb:
        params["srgb"] = True
    if args.evaluate:
        params["evaluate"] = True
    if args.baseline:
        params["baseline"] = True
    if args.no_show:
        params["persist"] = False
    if args.no_measure:
        params["measure"] = False
    return params


def compensate_report(result: dict) -> str:
    s = result.get("solve", {})
    lines = [f"compensated {result.get('image')} ({result['content_size'][0]}x{result['content_size'][1]}, "
             f"{result.get('channels')} channel(s)): {s.get('iterations')} iterations in {_fmt(s.get('seconds'), 2)} s "
             f"({s.get('reason')}), objective {s.get('initial_objective', 0):.5g} -> {s.get('objective', 0):.5g}",
             f"target white: {result.get('target_level')} camera units ({result.get('target_level_from')})"]
    t = result.get("transport", {})
    if t:
        lines.append(f"light transport: {'stored' if t.get('reused') else 'measured now'}, {t.get('captures')} captures")
    b = result.get("baseline")
    if b:
        lines.append(f"baseline: {len(b['slots'])} solves, {b['iterations']} iterations in {_fmt(b['solve_seconds_sum'], 2)} s "
                     f"({result.get('baseline_over_ours_seconds')} x ours)")
    q = result.get("quality")
    if q:
        lines.append(f"{'':<10} {'PSNR dB':>9} {'SSIM':>8}   (captured, {q['captures_averaged']} frames averaged)")
        for k in ("none", "baseline", "ours"):
            if k in q:
                lines.append(f"{k:<10} {q[k]['psnr']:>9.2f} {q[k]['ssim']:>8.4f}")
        lines.append(f"side by side: {q['picture']} in the rig directory")
    if result.get("content"):
        lines.append(result["content"])
    return "\n".join(lines)


def run_compensate(args: argparse.Namespace) -> int:
    return run_job_command(args, "compensate", compensate_params(args), report=compensate_report)


configure = configure_compensate
run = run_compensate
