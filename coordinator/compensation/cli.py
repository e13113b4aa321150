"""`shadowless response`, `shadowless transport` and `shadowless compensate`: the blur-compensation
jobs, run on the coordinator with a progress bar per stage.

Every job option's flag comes from the job's options dataclass (:mod:`.options`); only what
the operator gives is sent, the defaults apply on the coordinator. Images named on the command
line are read here and sent with the job, so the coordinator may run on another machine;
results (LUTs, the light transport, the compensated content, the quality picture) are stored
in the rig directory on the coordinator's machine.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from coordinator.client import add_connection_args
from coordinator.compensation.image_param import encode_image_param
from coordinator.compensation.options import CAMERA, CompensateOptions, ResponseOptions, TransportOptions
from coordinator.job_command import run_job_command
from coordinator.jobs.options import add_arguments, params_from_args

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


def _group(p: argparse.ArgumentParser, title: str) -> argparse._ArgumentGroup:
    """The parser's argument group ``title`` (created by :func:`add_arguments` or here)."""
    for g in p._action_groups:
        if g.title == title:
            return g
    return p.add_argument_group(title)


def _common(p: argparse.ArgumentParser, options: type) -> None:
    """Connection, the job's option flags, and the command-line-only --camera and --json."""
    add_connection_args(p)
    add_arguments(p, options)
    _group(p, CAMERA).add_argument(
        "--camera", dest="cameras", action="append", metavar="SPEC",
        help="camera(s) for this run: room://HOST:PORT, opencv:INDEX, ... (default: the coordinator's)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _params(args: argparse.Namespace, options: type) -> dict:
    params = params_from_args(options, args)
    if args.cameras:
        params["cameras"] = list(args.cameras)
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
    _common(p, ResponseOptions)


def response_params(args: argparse.Namespace) -> dict:
    return _params(args, ResponseOptions)


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
    _common(p, TransportOptions)


def transport_params(args: argparse.Namespace) -> dict:
    return _params(args, TransportOptions)


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
    _common(p, CompensateOptions)


def compensate_params(args: argparse.Namespace) -> dict:
    f = Path(args.image)
    try:
        image = encode_image_param(f)
    except OSError as exc:
        raise SystemExit(f"shadowless compensate: cannot read {f}: {exc.strerror or exc}") from None
    return {"image": image, **_params(args, CompensateOptions)}


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
