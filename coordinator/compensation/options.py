"""The options of the blur-compensation jobs, each defined once: the dataclass the job
receives, its validation, its command-line flag and its documentation all come from the
field (:mod:`coordinator.jobs.options`).

Only the standard library, :mod:`coordinator.jobs.options` and the argparse types it uses are
imported here, so the commands that build their flags from these classes start quickly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from coordinator.jobs.errors import JobError
from coordinator.jobs.options import option
from protos import cli_types

__all__ = ["ResponseOptions", "TransportOptions", "CompensateOptions", "SequenceOptions", "VideoOptions",
           "METHODS", "REGULARIZATION", "MESH_REGULARIZATION"]

#: the solver's methods (as :data:`imaging.compensation.solver.METHODS`, without importing SciPy)
METHODS = ("apg", "steepest", "lbfgsb")
#: default ridge weight of the solves, relative to ||L||^2 (:data:`imaging.compensation.ridge.DEFAULT_REGULARIZATION`)
REGULARIZATION = 0.02
#: the image solve's default on a mesh rig: on the room's bust the captured PSNR and SSIM rose as the ridge fell
#: from 0.02 to 0.001 and no fitted noise showed; 0.002 keeps the solve near 100 iterations (0 took all 300)
MESH_REGULARIZATION = 0.002

CAMERA = "camera and captures"
MEASURE = "what to measure"
TRANSPORT = "light transport"
SOLVE = "solve"
EVALUATION = "evaluation"
VIDEO = "video (a video file, a folder of images or --asset)"


def _reference(value: Any) -> str | float:
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise JobError("reference must be a slot name or a luminance (camera units above black)")
    if isinstance(value, str):
        return value
    if not (math.isfinite(value) and value > 0):
        raise JobError("a reference luminance must be positive")
    return float(value)


def _reference_text(text: str) -> str | float:
    """``--reference``: a number is a luminance, anything else a slot name."""
    try:
        return float(text)
    except ValueError:
        return text


def _image(value: Any) -> dict:
    if not isinstance(value, dict) or not isinstance(value.get("data"), str):
        raise JobError("image parameter must be {\"name\": ..., \"data\": base64}")
    return value


def _images(value: Any) -> list[dict]:
    if not isinstance(value, list) or not value:
        raise JobError("frames must be a non-empty list of images")
    return [_image(v) for v in value]


def _camera_indices(value: Any) -> list[int]:
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    if not isinstance(value, (list, tuple)) or not value:
        raise JobError("camera_indices must be a non-empty list of camera indices, e.g. [0, 1, 2]")
    out = []
    for v in value:
        try:
            i = int(v)
        except (TypeError, ValueError):
            raise JobError(f"camera_indices must be whole numbers, got {v!r}") from None
        if isinstance(v, bool) or (isinstance(v, float) and v != i):
            raise JobError(f"camera_indices must be whole numbers, got {v!r}")
        out.append(i)
    if len(set(out)) != len(out):
        raise JobError(f"camera_indices lists a camera twice: {out}")
    return out


@dataclass(frozen=True, kw_only=True)
class _CaptureOptions:
    camera: int = option(0, lo=0, hi=64, flag="--camera-index", metavar="I", group=CAMERA,
                         help="which calibrated camera to use")
    settle_s: float = option(0.05, lo=0.0, hi=30.0, flag="--settle", metavar="S", group=CAMERA,
                             help="wait after every swap before capturing, seconds")
    force: bool = option(False, label="Measure again", help="measure again instead of reusing stored results")


@dataclass(frozen=True, kw_only=True)
class ResponseOptions(_CaptureOptions):
    """Each projector's luminance response, its inverse LUT, the rig's brightness match and a linearity check."""

    slots: list[str] | None = option(None, group=MEASURE, help="only these projectors (default: every connected one)")
    mode: str = option("patches", choices=("patches", "full"), group=MEASURE,
                       help="patches: several grey levels per capture (needs the calibration); full: one uniform "
                            "level per capture")
    levels: int = option(17, lo=3, hi=256, metavar="K", group=MEASURE, help="grey levels from 0 to 1")
    grid: tuple[int, int] = option((4, 4), lo=1, hi=16, metavar="RxC", group=MEASURE, help="patches per frame")
    repeats: int = option(2, lo=1, hi=8, metavar="N", group=MEASURE, help="positions each grey level is shown at")
    reference: str | float | None = option(
        None, parse=_reference, cli_type=_reference_text, metavar="SLOT|LUMINANCE", group=MEASURE,
        help="match the rig's white to this projector's (measured) or to a camera luminance above black "
             "(default: gains 1, the headroom over the dimmest projector reported)")
    lut_entries: int = option(1024, lo=1024, hi=65536, metavar="E", group=MEASURE, help="LUT entries")
    frames: int = option(1, lo=1, hi=64, metavar="F", group=CAMERA,
                         help="captures averaged per pattern (raise it when a projector alone is dim in the camera: "
                              "its fitted curve carries the camera's noise)")
    verify_levels: int = option(6, lo=3, hi=64, metavar="K", group=MEASURE,
                                help="linear levels shown through the LUTs to check linearity")
    tolerance: float = option(0.01, lo=1e-4, hi=0.5, metavar="T", group=MEASURE,
                              help="largest deviation from a straight line, fraction of full scale")
    seed: int = option(0, lo=0, hi=2**31, metavar="N", group=MEASURE, help="seed of the patch layout")
    keep_going: bool = option(True, help="measure the other projectors when one fails")


@dataclass(frozen=True, kw_only=True)
class TransportOptions(_CaptureOptions):
    """The rig's light transport ``L`` from dot-grid captures, every projector at once (+ the baseline's ``L_i``)."""

    slots: list[str] | None = option(None, help="projectors that must take part (default: every connected one with "
                                                "a pose)")
    radius: int | None = option(None, lo=1, hi=16, metavar="R", group=TRANSPORT,
                                help="PSF recovery radius in camera pixels (default: from the geometry; on a mesh "
                                     "twice that, the part beyond it averaged over neighbouring texels)")
    spacing: int | None = option(None, lo=2, hi=64, metavar="S", group=TRANSPORT,
                                 help="dot-grid spacing in content pixels (default: the smallest that separates the "
                                      "windows; S*S captures)")
    frames: int | None = option(None, lo=1, hi=256, metavar="F", group=TRANSPORT,
                                help="captures averaged per pattern (default 1)")
    baseline: bool = option(False, help="also measure each projector's L_i, one at a time (N times the captures)")
    baseline_frames: int | None = option(None, lo=1, hi=4096, metavar="F", group=TRANSPORT,
                                         help="captures averaged per pattern for the per-projector baseline "
                                              "(default: frames)")
    baseline_exposure: float = option(1.0, lo=1e-3, hi=1e4, metavar="X", group=TRANSPORT,
                                      help="camera exposure of the baseline's captures relative to the camera's own "
                                           "(cameras that can set it; e.g. N, as one projector gives 1/N of the light)")
    camera_indices: list[int] | None = option(
        None, parse=_camera_indices, cli_type=cli_types.int_list(0, 64), lo=0, hi=64, flag="--camera-indices",
        metavar="I,J,...", group=CAMERA,
        help="a mesh rig: several calibrated cameras measure L together (each captures every dot pattern; each texel "
             "from the cameras that see it well; instead of --camera-index; compensate with the same list)")

    @property
    def camera_list(self) -> tuple[int, ...]:
        """The calibrated cameras the measurement uses: ``camera_indices``, or ``camera`` alone."""
        return tuple(self.camera_indices) if self.camera_indices else (self.camera,)

    @property
    def frame_count(self) -> int:
        """Captures averaged per dot pattern."""
        return self.frames or 1

    @property
    def baseline_frame_count(self) -> int:
        """Captures averaged per dot pattern of the baseline."""
        return self.baseline_frames or self.frame_count

    @property
    def given(self) -> dict[str, int]:
        """The measurement options the caller set (radius, spacing, frames): a stored ``L`` must match only these."""
        return {k: getattr(self, k) for k in ("radius", "spacing", "frames") if getattr(self, k) is not None}


@dataclass(frozen=True, kw_only=True)
class CompensateOptions(TransportOptions):
    """One bounded least-squares solve for an image; the result stored as the rig's content and shown."""

    image: dict | None = option(None, parse=_image, cli=False,
                                help="the image: {\"name\", \"data\"} with the file's bytes, zlib + base64 "
                                     "(coordinator.compensation.image_param.encode_image_param); with neither this "
                                     "nor image_path, the image the rig shows (its content)")
    image_path: str | None = option(None, cli=False, help="an image file on the coordinator's machine, instead of image")
    srgb: bool = option(False, group=SOLVE, help="the image is sRGB-encoded (default: values are linear luminance, as "
                                                "`shadowless show` shows them)")
    level: float = option(0.9, lo=0.01, hi=1.0, metavar="F", group=SOLVE,
                          help="target white as a fraction of the rig's white (2nd percentile over the content); with "
                               "--baseline at most what the dimmest projector's share allows")
    max_iter: int = option(300, lo=1, hi=100_000, metavar="N", group=SOLVE, help="iteration budget")
    tol: float = option(1e-5, lo=0.0, hi=1.0, metavar="T", group=SOLVE, help="relative objective decrease that stops")
    est_tol: float = option(0.0, lo=0.0, hi=0.5, metavar="T", group=SOLVE,
                            help="also stop once the decrease still to come, extrapolated from the last 10 iterations, "
                                 "is at most this fraction of the objective (0.005: within about 0.6 percent of the "
                                 "optimum in a fraction of the iterations; 0: off; apg and steepest)")
    method: str = option("apg", choices=METHODS, group=SOLVE, help="solver")
    regularization: float | None = option(None, lo=0.0, hi=100.0, metavar="MU", group=SOLVE,
                                          help=f"ridge weight towards the uncompensated image, relative to ||L||^2 (0 "
                                               f"fits the measured L exactly, noise included; default {REGULARIZATION} "
                                               f"on a table, {MESH_REGULARIZATION} on a mesh)")
    persist: bool = option(True, flag="--show", group=SOLVE, label="Show the result",
                           help="make the result the rig's content and show it (--no-show: solve and store figures "
                                "only)")
    measure: bool = option(True, group=SOLVE, help="measure L when no valid one is stored (--no-measure: fail instead)")
    evaluate: bool = option(False, group=EVALUATION,
                            help="capture none / ours (/ baseline): PSNR, SSIM, compensation/quality.png in the rig "
                                 "directory")
    baseline: bool = option(False, group=EVALUATION,
                            help="also solve and show the per-projector baseline (its L_i are measured when missing: "
                                 "N times the captures)")
    eval_frames: int = option(4, lo=1, hi=256, metavar="F", group=EVALUATION,
                              help="captures averaged per evaluated result")


def _asset_key(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise JobError("asset must be the name, id or id prefix of a video asset in the rig's store")
    return value.strip()


def _asset_name(value: Any) -> str:
    if not isinstance(value, str) or not value.strip() or len(value.strip()) > 200:
        raise JobError("name must be 1-200 characters")
    return value.strip()


def _cluster_address(value: Any) -> str:
    text = value.strip() if isinstance(value, str) else ""
    if not text or len(text) > 200 or any(c.isspace() for c in text):
        raise JobError("cluster must be a Dask scheduler's address, e.g. tcp://10.0.0.5:8786")
    return text


#: --motion's choices: off, or the DIS optical flow preset (imaging.compensation.motion.PRESETS)
MOTION_FLOWS = ("off", "ultrafast", "fast", "medium")

#: frames per segment of a --cluster run when --segment-frames is not given (10 s at 24 fps: a cold
#: start's extra iterations cost ~6 % at the default budgets)
CLUSTER_SEGMENT_FRAMES = 240


@dataclass(frozen=True, kw_only=True)
class _FrameOptions:
    """What a frame-by-frame (warm-started) compensation needs: budgets, target level, ridge, transport."""

    iterations: int = option(4, lo=1, hi=10_000, metavar="N", group=VIDEO,
                             help="APG iterations per frame after the first")
    first_iterations: int = option(60, lo=1, hi=100_000, metavar="N", group=VIDEO,
                                   help="APG iterations of the first frame")
    level: float = option(0.9, lo=0.01, hi=1.0, metavar="F", group=SOLVE,
                          help="target white, as a fraction of the rig's white (as for an image)")
    srgb: bool = option(False, group=SOLVE, help="the frames are sRGB-encoded (default: values are linear luminance)")
    regularization: float = option(REGULARIZATION, lo=0.0, hi=100.0, metavar="MU", group=SOLVE,
                                   help="ridge weight towards the uncompensated frame, relative to ||L||^2")
    measure: bool = option(False, group=SOLVE,
                           help="measure L when no valid one is stored (default: fail; run `shadowless transport`)")
    camera: int = option(0, lo=0, hi=64, metavar="I", flag="--camera-index", group=CAMERA,
                         help="which calibrated camera L was measured with")
    motion: str = option("fast", choices=MOTION_FLOWS, metavar="FLOW", group=VIDEO,
                         help="follow the picture's motion: each frame may start from the previous correction moved "
                              "along the content's optical flow, as far as that lowers the start's objective (the blur's part "
                              "moves, the rig's pixel pattern stays); FLOW is the DIS preset (ultrafast, fast, medium: "
                              "more accurate and slower in that order). off: the correction stays in place, and on a "
                              "blurred rig a pan ends about 2.5 dB short of converged at 4 iterations (fast: within "
                              "0.5 dB)")


@dataclass(frozen=True, kw_only=True)
class SequenceOptions(_FrameOptions):
    """Frames compensated one after the other (warm starts), then played in sync."""

    frames: list = option(parse=_images, cli=False,
                          help="the images, in order ({\"name\", \"data\"} each, as CompensateOptions.image)")
    fps: float = option(30.0, lo=0.1, hi=1000.0, metavar="FPS", help="playback rate")
    loops: int = option(0, lo=0, hi=10_000, metavar="N", help="extra loops of the playback")
    play: bool = option(True, help="play the compensated frames (--no-play: only compensate)")


@dataclass(frozen=True, kw_only=True)
class VideoOptions(_FrameOptions):
    """A video asset compensated frame by frame (warm starts) into a new 16-bit FFV1 asset."""

    measure: bool = option(True, group=SOLVE, help="measure L when no valid one is stored (--no-measure: fail instead)")
    asset: str = option(parse=_asset_key, cli=False,
                        help="the source: name, id or id prefix of a video (or image-sequence) asset in the rig's store")
    name: str | None = option(None, parse=_asset_name, metavar="NAME", group=VIDEO,
                              help="name of the compensated asset (default: the source's name + ' (compensated)')")
    max_frames: int | None = option(None, lo=1, hi=10_000_000, metavar="N", group=VIDEO,
                                    help="compensate only the first N frames (a trial run)")
    resume: bool = option(True, group=VIDEO,
                          help="continue a stopped run of the same source and solve options from its last checkpoint "
                               "(--no-resume: start over)")
    checkpoint_s: float = option(10.0, lo=0.0, hi=3600.0, flag="--checkpoint", metavar="S", group=VIDEO,
                                 help="seconds between checkpoints a stopped run resumes from (0: after every frame)")
    psnr: bool = option(True, group=VIDEO,
                        help="predict each frame's PSNR through the measured L, uncompensated and ours (2 products "
                             "with L per frame)")
    segment_frames: int | None = option(None, lo=1, hi=10_000_000, metavar="N", group=VIDEO,
                                        help="solve the video in independent segments of N frames, each from a cold "
                                             "start (--first-iterations at its first frame); the same N gives the "
                                             "same bytes with or without --cluster (default: one warm-started run; "
                                             f"with --cluster {CLUSTER_SEGMENT_FRAMES})")
    cluster: str | None = option(None, parse=_cluster_address, metavar="ADDRESS", group=VIDEO,
                                 help="solve the segments on the workers of this Dask scheduler (tcp://HOST:8786; "
                                      "needs shadowless[cluster] on the coordinator and the workers)")

    @property
    def segment_length(self) -> int | None:
        """Frames per independently solved segment (None: every frame warm-started from the one before)."""
        return self.segment_frames or (CLUSTER_SEGMENT_FRAMES if self.cluster else None)
