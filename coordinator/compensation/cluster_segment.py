"""What a Dask worker runs for ``compensate_video --cluster``: one segment of the video, decoded
from the source's bytes, solved from a cold start and encoded as a 16-bit FFV1 segment file.

A segment is frames ``[start, start + count)``; the segment boundary rule (:func:`segments`) is
the one a single-machine run of ``--segment-frames N`` follows (its warm start is reset at every
multiple of ``N``), so both give the same frames. The worker receives, once, the
:class:`SegmentSpec` (the light transport ``L`` and what the solve needs; scattered to every
worker by the coordinator, :mod:`.cluster`) and the source's bytes (a video file, also scattered
once; an image sequence's frames are sent with their segment). It reads nothing from the
coordinator's disk, so a worker may run on any machine that has ``shadowless[coordinator,cluster]``
installed. The ridge problem built over ``L`` is kept per worker process between segments of the
same run (its step size takes a few power iterations).

The worker reports each solved frame as a Dask event (topic :data:`TOPIC`: ``{"key", "start",
"done", "worker"}``), from which the coordinator shows progress inside segments. The result
(:class:`SegmentResult`) carries the segment file's bytes and the per-frame figures.
"""
from __future__ import annotations

import io
import threading
import time
from dataclasses import dataclass, field
from fractions import Fraction

from coordinator.compensation.frames import FrameSolver, motion_warp
from imaging.compensation.ridge import ContentWarmStart, RidgeProblem
from coordinator.compensation.store import StoredTransport
from coordinator.compensation.video_io import Ffv1Writer, SourceFrames
from protos.asset_manifest import Manifest

__all__ = ["SegmentSpec", "SegmentResult", "SequenceFrames", "segments", "solve_segment", "TOPIC", "frame_solver"]


def segments(total: int, length: int) -> list[tuple[int, int]]:
    """The segments ``(start, count)`` of ``total`` frames cut every ``length`` frames: frame ``k`` is
    in segment ``k // length``, the last one shorter when ``length`` does not divide ``total``."""
    if total < 0 or length < 1:
        raise ValueError(f"total must be >= 0 and length >= 1, got {total}, {length}")
    return [(s, min(length, total - s)) for s in range(0, total, length)]


#: the Dask event topic the workers report their frames on (each event names its run's key)
TOPIC = "shadowless-video"


@dataclass(frozen=True)
class SegmentSpec:
    """What every worker needs for every segment of one run (sent once per worker).

    ``transport`` is the stored light transport (``L``: ``(n_camera, n_content)`` float32 CSR;
    ``H``: content -> camera homography); ``size`` the content size ``(W, H)``; ``level`` the
    target white in camera units; ``region`` the camera rows/cols of the PSNR figures;
    ``rate`` the source's exact frame rate; ``motion`` the ``--motion`` flow
    (:func:`~.frames.motion_warp`); ``key`` names the run (the worker's cached problem and the
    event topic).
    """

    key: str
    transport: StoredTransport
    regularization: float
    iterations: int
    first_iterations: int
    motion: str
    size: tuple[int, int]
    level: float
    region: tuple[slice, slice]
    srgb: bool
    predict: bool
    manifest: Manifest
    rate: Fraction


@dataclass(frozen=True)
class SequenceFrames:
    """An image-sequence segment's frame files: ``data[k]`` is frame ``start + k``'s bytes."""

    start: int
    data: list[bytes]


@dataclass(frozen=True)
class SegmentResult:
    """A solved segment: ``data`` is its FFV1 Matroska file (empty when the source had no frame
    left at ``start``); ``frames`` how many it holds (fewer than asked at the source's end);
    per-frame solve ``times`` (s), data ``objectives``, ``psnrs`` (predicted, none/ours) and
    motion starts' ``shares`` (:attr:`.ridge.ContentWarmStart.last_share`);
    ``scale`` the content -> target scale of its first frame; the worker's address and seconds
    spent decoding, solving and encoding."""

    start: int
    frames: int
    data: bytes
    times: list[float] = field(default_factory=list)
    objectives: list[float] = field(default_factory=list)
    psnrs: list[tuple[float, float]] = field(default_factory=list)
    shares: list[float] = field(default_factory=list)
    scale: float | None = None
    worker: str = ""
    decode_s: float = 0.0
    solve_s: float = 0.0
    encode_s: float = 0.0


_lock = threading.Lock()
_problems: dict[str, RidgeProblem] = {}


def frame_solver(spec: SegmentSpec) -> FrameSolver:
    """A cold-started :class:`FrameSolver` for ``spec`` (built as the coordinator builds its own,
    :func:`~.frames.open_frame_solver`), over this process's cached ridge problem."""
    with _lock:
        problem = _problems.get(spec.key)
        if problem is None:
            _problems.clear()   # one run at a time per worker: drop the previous run's L
            problem = _problems[spec.key] = RidgeProblem(spec.transport.L, spec.regularization)
    w, h = spec.size
    warm = ContentWarmStart(problem, iterations=spec.iterations, first_iterations=spec.first_iterations,
                            content_shape=(h, w), motion=motion_warp(spec.motion))
    return FrameSolver(spec.transport, problem, warm, (w, h), spec.level, spec.region, srgb=spec.srgb)


def _reporter(key: str, start: int):
    """``report(done)``: a Dask event per solved frame when running on a worker; nothing elsewhere."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return "", lambda done: None
    return worker.address, lambda done: worker.log_event(TOPIC, {"key": key, "start": start, "done": done,
                                                                 "worker": worker.address})


def solve_segment(spec: SegmentSpec, source: bytes | SequenceFrames, start: int, count: int) -> SegmentResult:
    """Frames ``[start, start + count)`` of the source decoded, compensated from a cold start and
    written as a 16-bit FFV1 segment (blocking; a Dask task). ``source``: the video file's bytes,
    or the segment's image files."""
    solver = frame_solver(spec)
    address, report = _reporter(spec.key, start)
    if isinstance(source, SequenceFrames):
        seq = source
        frames = SourceFrames(spec.manifest, lambda k: seq.data[k - seq.start], rate=spec.rate, start=start,
                              stop=start + count)
    else:
        frames = SourceFrames(spec.manifest, lambda k: source, rate=spec.rate, start=start, stop=start + count)
    decode_s = encode_s = 0.0
    it = iter(frames)
    buf = io.BytesIO()          # in memory: a worker killed mid-segment leaves no file behind
    writer: Ffv1Writer | None = None
    try:
        while True:
            t = time.perf_counter()
            image = next(it, None)
            decode_s += time.perf_counter() - t
            if image is None:
                break
            out = solver.solve(image, predict=spec.predict)
            t = time.perf_counter()
            if writer is None:
                writer = Ffv1Writer(buf, size=solver.size, channels=out.frame.shape[2], rate=spec.rate, first=start)
            writer.write(out.frame)
            encode_s += time.perf_counter() - t
            report(writer.frames)
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        it.close()   # closes the video file
    t = time.perf_counter()
    if writer is not None:
        writer.close()
    data = buf.getvalue()
    encode_s += time.perf_counter() - t
    return SegmentResult(start=start, frames=len(solver.times), data=data, times=list(solver.times),
                         objectives=list(solver.objectives), psnrs=list(solver.psnrs), shares=list(solver.shares),
                         scale=solver.warm.scale,
                         worker=address, decode_s=decode_s, solve_s=float(sum(solver.times)), encode_s=encode_s)
