"""`shadowless response`, `shadowless transport` and `shadowless compensate` (an image, or a video
into a compensated asset): the blur-compensation jobs, run on the coordinator with a progress bar
per stage.

Every job option's flag comes from the job's options dataclass (:mod:`.options`); only what
the operator gives is sent, the defaults apply on the coordinator. Images named on the command
line are read here and sent with the job, so the coordinator may run on another machine;
results (LUTs, the light transport, the compensated content, the quality picture) are stored
in the rig directory on the coordinator's machine.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from rigctl.client import add_connection_args
from coordinator.errors import OPERATOR_ERRORS
from coordinator.compensation.image_param import encode_image_param
from coordinator.compensation.options import CAMERA, CompensateOptions, ResponseOptions, TransportOptions, VideoOptions
from rigctl.job_command import run_job_command
from coordinator.jobs.options import add_arguments, params_from_args
from protos.wording import count

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
        lines.append(f"brightness: reference {b['reference']}; gain {b['gain']:.4f}, headroom {b['headroom']:.3f} x"
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


def _tail_note(result: dict) -> str:
    """How a mesh ``L`` was measured: its windows' core per texel, the tail beyond averaged over neighbours,
    the camera's exposure when the rig's white needed a lower one, and the dots' longer one."""
    note = f", tail beyond {result['core']} averaged over neighbouring texels" if result.get("tails_averaged") else ""
    if result.get("exposure", 1.0) < 1.0:
        note += (f"; at {result['exposure']:.3f} times the camera's exposure (the white reached "
                 f"{result.get('white_peak', float('nan')):.2f} of its full scale)")
    if result.get("dot_gain", 1.0) > 1.0:
        note += f"; the dots at {result['dot_gain']:.2f} times the white's exposure"
    return note


def transport_report(result: dict) -> str:
    lines = [f"light transport {'reused (unchanged rig)' if result.get('reused') else 'measured'}: "
             f"{result.get('captures')} captures ({result.get('patterns')} dot patterns, spacing {result.get('spacing')}, "
             f"radius {result.get('radius')}{_tail_note(result)}), {result.get('nnz')} non-zeros, {count(result.get('slots') or 0, 'projector')}",
             f"stored in the rig directory: {result.get('file')} ({result.get('date')})"]
    w = result.get("white")
    if w:
        lines.append(f"rig white inside the content: 2nd percentile {w['p2']}, median {w['median']} (camera units)")
    b = result.get("baseline")
    if b:
        lines.append(f"baseline: {count(len(b['slots']), 'projector')}, {b['captures']} captures this run "
                     f"({b['captures_per_projector']} per projector) in {_fmt(b['seconds'], 1)} s"
                     + (f"; left out (no light): {', '.join(b['excluded'])}" if b.get("excluded") else ""))
    return "\n".join(lines)


def run_transport(args: argparse.Namespace) -> int:
    return run_job_command(args, "transport", transport_params(args), report=transport_report)


# ---------------------------------------------------------------- compensate
#: options both compensate jobs take, with the same flag and meaning
SHARED = ("level", "srgb", "regularization", "measure", "camera")

def configure_compensate(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Compensate the rig's blur for an image or a video.\n\n"
        "An IMAGE: one bounded least-squares solve over the summed light transport (progress: iteration and\n"
        "objective); the result is stored as the rig's content and shown on every projector. --evaluate\n"
        "captures the image without compensation, with ours (and with --baseline, the per-projector method)\n"
        "and scores each against the target (PSNR, SSIM).\n\n"
        "A VIDEO (.mp4 .mov .mkv .avi, or a folder of images as a sequence) or --asset NAME (a video asset\n"
        "already in the rig's store): every frame is solved warm-started from the previous one (--iterations\n"
        "per frame, --first-iterations for the first; progress with ETA), and the result is written as a new\n"
        "asset, '<name> (compensated)': lossless 16-bit FFV1 in Matroska, at the content size and the source's\n"
        "exact frame rate. Nodes fetch it like any asset; play it by timeline with `shadowless play NAME`.\n"
        "Nothing partial enters the store; a stopped run (Ctrl-C, a crash) keeps its frames up to the last\n"
        "checkpoint (--checkpoint S) in the rig directory, and the same command run again resumes there.\n"
        "A video FILE is added to the store first, as `shadowless content add` does: straight into the rig\n"
        "directory on the coordinator's machine (--rig-dir), uploaded from any other machine (--coordinator\n"
        "HOST:PORT or --rig NAME, with --token-file; resumable, checked by SHA-256).\n\n"
        "A long video on a Dask cluster (--cluster ADDRESS): the video is cut into segments of --segment-frames\n"
        "frames, each solved on a worker from a cold start; L and the source are sent to each worker once, the\n"
        "segments come back as they finish and are joined in order (a finished segment survives a restart; a\n"
        "worker that dies has its segment solved again). --segment-frames N here gives the same bytes."
    )
    p.epilog = EXAMPLES + """
videos:
  shadowless compensate --rig-dir rigs/table show.mp4            # add, compensate -> 'show (compensated)'
  shadowless compensate --rig-dir rigs/table --asset show --max-frames 30   # a trial on 30 frames
  shadowless play --rig-dir rigs/table "show (compensated)"      # by timeline, like any asset
  shadowless compensate show.mp4 --coordinator 10.0.0.2:7600 --token-file table.token   # from a laptop
  shadowless compensate --rig-dir rigs/table --asset show --cluster tcp://10.0.0.5:8786   # on Dask workers
  shadowless compensate --rig-dir rigs/table --asset show --segment-frames 240   # the same bytes, here

a cluster (pip install 'shadowless[cluster]' on the coordinator and on every worker machine):
  dask scheduler --port 8786                       # one machine
  dask worker tcp://10.0.0.5:8786 --nthreads 1     # every other machine (one solve per core is enough)
"""
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("source", nargs="?", metavar="IMAGE|VIDEO",
                   help="image file (PNG/TIFF/JPEG, 8 or 16 bit, or .npy float32 in [0, 1]), or a video file "
                        "(.mp4 .mov .mkv .avi) or folder of images, added to the rig's store on this machine first")
    p.add_argument("--asset", metavar="NAME|ID",
                   help="compensate a video (or image-sequence) asset already in the rig's store: its name, id or id "
                        "prefix (see `shadowless content list`)")
    _common(p, CompensateOptions)
    add_arguments(p, VideoOptions, exclude=SHARED)


def _is_video(path: Path) -> bool:
    from coordinator.asset_probe import VIDEO_SUFFIXES

    return path.is_dir() or path.suffix.lower() in VIDEO_SUFFIXES


def compensate_request(args: argparse.Namespace) -> tuple[str, dict]:
    """The job to run for ``shadowless compensate``: ``("compensate", params)`` for an image,
    ``("compensate_video", params)`` for a video file (added to the local store first) or ``--asset``."""
    if args.asset and args.source:
        raise SystemExit("shadowless compensate: give a file or --asset, not both")
    if args.asset:
        return "compensate_video", video_params(args, args.asset)
    if not args.source:
        raise SystemExit("shadowless compensate: give an image or video file, or --asset NAME (a video in the rig's "
                         "store)")
    f = Path(args.source)
    if _is_video(f):
        return "compensate_video", video_params(args, add_local_video(args, f))
    return "compensate", compensate_params(args)


def compensate_params(args: argparse.Namespace) -> dict:
    """An image's job parameters: the file's bytes and the flags given."""
    f = Path(args.source)
    video_only = sorted(set(params_from_args(VideoOptions, args, exclude=SHARED)))
    if video_only:
        raise SystemExit(f"shadowless compensate: {', '.join('--' + k.replace('_', '-') for k in video_only)} "
                         "appl(ies) to a video only")
    try:
        image = encode_image_param(f)
    except OSError as exc:
        raise SystemExit(f"shadowless compensate: cannot read {f}: {exc.strerror or exc}") from None
    return {"image": image, **_params(args, CompensateOptions)}


def video_params(args: argparse.Namespace, asset: str) -> dict:
    """A video's job parameters: the asset (name or id) and the flags given; image-only flags refused."""
    image_only = sorted(set(params_from_args(CompensateOptions, args)) - set(SHARED))
    if image_only:
        raise SystemExit(f"shadowless compensate: {', '.join('--' + k.replace('_', '-') for k in image_only)} "
                         "appl(ies) to an image only (for a video, measure L first: `shadowless transport`)")
    return {"asset": asset, **_params(args, VideoOptions)}


def add_local_video(args: argparse.Namespace, path: Path) -> str:
    """Add a video file (or folder of images) to the rig's store on this machine; its asset id."""
    from rigctl.content_commands import open_store  # only this path needs the store
    from coordinator.errors import AssetError

    if not path.exists():
        raise SystemExit(f"shadowless compensate: {path}: no such file or folder (a video already in the rig's store: "
                         "--asset NAME)")
    if not (args.rig_dir and (Path(args.rig_dir) / "rig.toml").is_file()):
        return upload_video(args, path)
    try:
        store = open_store(args.rig_dir)
        known = {aid for aid, _ in store.list()}
        m = store.add(path, note=lambda text: print(f"note: {text}", file=sys.stderr))
    except AssetError as exc:
        raise SystemExit(f"shadowless compensate: {exc}") from None
    if m.kind == "still":
        raise SystemExit(f"shadowless compensate: {path} is a still image")
    state = "already in the store" if m.asset_id in known else f"added to the store ({m.total_bytes / 1e6:.1f} MB)"
    print(f"{m.kind} {m.name!r} ({m.asset_id[:12]}): {m.frames} frames, {m.width}x{m.height}, {m.fps:g} fps, {state}",
          file=sys.stderr)
    return m.asset_id


def upload_video(args: argparse.Namespace, path: Path) -> str:
    """Upload a video file (or folder of images) to the running coordinator's store (as `content
    add --coordinator`: resumable, checked by hash); its asset id."""
    import asyncio

    from rigctl.client import CallRefused
    from rigctl.rig_target import open_client
    from rigctl.content_remote import upload

    async def go() -> str:
        async with await open_client(args) as c:
            m, existed, notes, sent = await upload(c, path, name=None, fps=None)
        for text in notes:
            print(f"note: {text}", file=sys.stderr)
        if m.kind == "still":
            raise SystemExit(f"shadowless compensate: {path} is a still image")
        state = "already in the store" if existed else f"uploaded to the store ({sent / 1e6:.1f} MB sent)"
        print(f"{m.kind} {m.name!r} ({m.asset_id[:12]}): {m.frames} frames, {m.width}x{m.height}, {m.fps:g} fps, "
              f"{state}", file=sys.stderr)
        return m.asset_id

    try:
        return asyncio.run(go())
    except CallRefused as exc:
        raise SystemExit(f"shadowless compensate: the coordinator refused the upload: {exc.details}") from None
    except (*OPERATOR_ERRORS, OSError) as exc:
        raise SystemExit(f"shadowless compensate: {exc}") from None


def video_report(result: dict) -> str:
    src, a = result.get("source", {}), result.get("asset", {})
    lines = [f"compensated {result.get('frames')} frame(s) of {src.get('name')!r} at {a.get('rate')} fps: "
             f"{_fmt(result.get('seconds_per_frame'), 3)} s per frame (solve: first {_fmt(result.get('ms_first_frame'), 0)} "
             f"ms, then {_fmt(result.get('ms_per_frame_mean'), 0)} ms mean at {result.get('iterations_per_frame')} "
             "iterations)",
             f"asset {a.get('name')!r} {a.get('id', '')[:12]}: {a.get('size', ['?', '?'])[0]}x{a.get('size', ['?', '?'])[1]}, "
             f"{a.get('channels')} x {a.get('bit_depth')}-bit {a.get('codec')}, {a.get('bytes', 0) / 1e6:.1f} MB"
             + (" (already stored: the same result as before)" if a.get("already_stored") else "")]
    p = result.get("predicted_psnr")
    if p:
        lines.append(f"predicted PSNR through the measured L (mean): none {p['none_mean']:.2f} dB -> ours "
                     f"{p['ours_mean']:.2f} dB (worst frame {p['ours_min']:.2f} dB)")
    if result.get("note"):
        lines.append(result["note"])
    lines.append(f"play it by timeline: shadowless play {json.dumps(a.get('name') or a.get('id'))}")
    return "\n".join(lines)


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
    kind, params = compensate_request(args)
    return run_job_command(args, kind, params, report=video_report if kind == "compensate_video" else compensate_report)


configure = configure_compensate
run = run_compensate
