"""The ``compensate_video`` job: a video asset compensated frame by frame into a new asset.

The source is a ``video`` (or image ``sequence``) asset in the rig's store, named by its name, id
or id prefix. Its frames are decoded on the coordinator (:class:`~.video_io.AssetFrames`),
resized to the rig's content size and solved one after the other, each warm-started from the
previous one (:class:`~.frames.FrameSolver`, as ``compensate_sequence``: ``first_iterations``
for the first frame, ``iterations`` for each later one; ``motion`` moves the previous correction
along the content's optical flow as far as that lowers the start's objective,
:class:`~.ridge.ContentWarmStart`). The compensated frames (``(H, W, C)``
uint16, ``rint(65535 x)``) are written as they come into lossless 16-bit FFV1 segments
(:class:`~.video_io.Ffv1Writer`), joined at the end into one Matroska file at the source's exact
frame rate (:func:`~.video_io.join_segments`), and added to the store as the asset
``<source name> (compensated)``, which plays by timeline like any other (`shadowless play ASSET`).

Nothing partial reaches the store: the files are written under ``compensation/video-tmp/`` in
the rig directory, in a folder named by what decides the frames (source, light transport, solve
options, content size); the asset is added (content-addressed, manifest last,
:meth:`AssetStore.add`) only once complete, and the folder removed. Every ``checkpoint_s`` the
open segment is closed and the solver's warm-start state saved (``state.npz``, atomically, naming
the finished segments); a cancelled, failed or killed run keeps them, and the same job run again
continues from the last checkpoint and gives the same bytes, hence the same asset, as a run never
stopped. Folders untouched for a week are removed. The figures go to ``compensation/video.json``.

``segment_frames`` (``--segment-frames N``) cuts the video into segments of ``N`` frames solved
independently: the warm start is reset at every multiple of ``N`` (``first_iterations`` there).
``cluster`` (``--cluster ADDRESS``) solves those segments on the workers of a Dask cluster
(:mod:`.cluster`; 240 frames each unless ``segment_frames`` says otherwise); the same ``N`` gives
the same bytes on a cluster and here.
"""
from __future__ import annotations

import functools
import hashlib
import json
import logging
import re
import shutil
import threading
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from coordinator.assets import AssetStore
from imaging.compensation.errors import CompensationError
from coordinator.compensation.frames import FrameSolver, SolvedFrame, open_frame_solver
from coordinator.compensation.options import VideoOptions
from coordinator.compensation.store import compensation_dir, write_result
from coordinator.compensation.video_io import AssetFrames, Ffv1Writer, join_segments
from coordinator.errors import AssetError
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures, JobResult, optional, spread
from coordinator.show import manifest_rate
from protos.store import atomic_file
from protos.asset_manifest import Manifest

__all__ = ["OPTIONS", "run", "compensated_name", "run_key", "VideoResult"]

log = logging.getLogger(__name__)

OPTIONS = VideoOptions

#: folder (in the rig's compensation directory) of the runs being written
TMP_DIR = "video-tmp"
#: a stopped run's folder untouched this long is removed by the next run
STALE_S = 7 * 24 * 3600.0
STATE = "state.npz"


@dataclass(frozen=True, kw_only=True)
class VideoResult(JobResult):
    """The ``compensate_video`` job's result (also ``compensation/video.json``): the source and the stored
    asset, the frames' figures (:meth:`~coordinator.compensation.frames.FrameSolver.summary`) at the top,
    how the run went (segments, resumption, decoding and encoding time), the cluster's figures on a
    cluster, a note when fewer frames than the source's were compensated, and the job's wall time."""

    source: Figures
    asset: Figures
    frame_figures: Figures = spread()
    segment_frames: int | None
    resumed_from: int
    seconds_per_frame: float | None
    decode_s: float
    encode_s: float
    truncated: bool
    cluster: Figures | None = optional()
    note: str | None = optional()
    wall_s: float


def compensated_name(source: str) -> str:
    """The default name of a source's compensated asset: ``'<source> (compensated)'`` (at most 200 characters)."""
    suffix = " (compensated)"
    return source[: 200 - len(suffix)] + suffix


def _file_name(name: str) -> str:
    """A file name for the asset's one blob: its name with anything unusual replaced, ``.mkv``."""
    return (re.sub(r"[^\w .()+-]", "_", name).strip(" .") or "compensated")[:120] + ".mkv"


def _sweep(folder: Path, keep: Path) -> None:
    """Remove runs' folders in ``folder`` (but ``keep``) whose newest file is older than ``STALE_S``."""
    if not folder.is_dir():
        return
    now = time.time()
    for p in folder.iterdir():
        if p == keep:
            continue
        try:
            newest = max([p.stat().st_mtime, *(f.stat().st_mtime for f in p.rglob("*"))])
            if now - newest > STALE_S:
                shutil.rmtree(p, ignore_errors=True)
        except OSError:
            pass


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def run_key(source_id: str, transport: dict, opts: VideoOptions, size: tuple[int, int]) -> str:
    """What decides a run's frames, hashed: a stopped run resumes only into the same one."""
    what = {"source": source_id, "transport": [transport.get("fingerprint"), transport.get("date")],
            "size": list(size), **{k: getattr(opts, k) for k in ("iterations", "first_iterations", "level", "srgb",
                                                                 "regularization", "camera", "psnr")}}
    if opts.motion != "off":  # (absent when off: such a run keeps the key it had before the motion start)
        what["motion"] = opts.motion
    if opts.segment_length:   # (absent otherwise: a run without segments keeps its key, and its checkpoints)
        what["segment_frames"] = opts.segment_length
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:24]


class _Pipeline:
    """Decode -> solve -> encode, one frame per :meth:`step`, on worker threads one at a time.

    With ``segment``, the warm start is reset every ``segment`` frames (``--segment-frames``: the
    frames a cluster run gives, :mod:`.cluster`). Frames go into files ``seg-<first frame>.mkv`` in
    ``folder``; every ``checkpoint_s`` the
    open segment is closed and ``state.npz`` saved (the solver's state, the frames done, the
    finished segments). A lock makes :meth:`finish`, :meth:`stop` and :meth:`discard` wait for the
    frame in flight, so a cancelled job (whose ``await`` returns while its worker thread still
    runs) never closes a file under it.
    """

    def __init__(self, store: AssetStore, manifest: Manifest, solver: FrameSolver, folder: Path, rate: Fraction, *,
                 predict: bool, checkpoint_s: float, resume: bool, limit: int, segment: int | None = None) -> None:
        self.solver, self.folder, self.rate, self.predict, self.segment = solver, folder, rate, predict, segment
        self.checkpoint_s = checkpoint_s
        self.done, self.segments = 0, []
        folder.mkdir(parents=True, exist_ok=True)
        if resume:
            self._load()
        if self.done > limit:   # a stopped run went past this one's last frame: start over
            self._forget()
            resume = False
        self.resumed_from = self.done
        keep = {name for name, _ in self.segments} | {STATE}
        for f in folder.iterdir():   # segments after the checkpoint, an old state, a final file: not needed
            if f.name not in keep or not resume:
                f.unlink(missing_ok=True)
        self._frames = AssetFrames(store, manifest, start=self.done)
        self._it = iter(self._frames)
        self._lock = threading.Lock()
        self.writer: Ffv1Writer | None = None
        self._last_checkpoint = time.monotonic()
        self.decode_s = self.encode_s = 0.0

    def _load(self) -> None:
        try:
            with np.load(self.folder / STATE, allow_pickle=False) as z:
                saved = {k: z[k] for k in z.files}
            segments = [(str(n), int(c)) for n, c in json.loads(str(saved["segments"]))]
            done = int(saved["frames"])
            if sum(c for _, c in segments) != done or not all((self.folder / n).is_file() for n, _ in segments):
                raise ValueError("its segments do not add up")
            self.solver.restore(saved)
        except FileNotFoundError:
            return
        except (OSError, ValueError, KeyError) as exc:   # a damaged checkpoint: start over
            log.warning("video compensation: checkpoint in %s not usable (%s); starting over", self.folder, exc)
            self._forget()
            return
        self.done, self.segments = done, segments

    def _forget(self) -> None:
        """Start over: no frames done, the solver as new."""
        self.done, self.segments = 0, []
        self.solver.warm.reset()
        self.solver.times, self.solver.objectives, self.solver.psnrs, self.solver.shares = [], [], [], []

    def step(self) -> SolvedFrame | None:
        """The next frame decoded, compensated and written; None at the end of the source."""
        with self._lock:
            t = time.perf_counter()
            image = next(self._it, None)
            self.decode_s += time.perf_counter() - t
            if image is None:
                return None
            if self.segment and self.done % self.segment == 0:
                self.solver.warm.reset()   # a segment's first frame: a cold start, as on a cluster
            out = self.solver.solve(image, predict=self.predict)
            t = time.perf_counter()
            if self.writer is None:
                self.writer = Ffv1Writer(self.folder / f"seg-{self.done:08d}.mkv", size=self.solver.size,
                                         channels=out.frame.shape[2], rate=self.rate, first=self.done)
            self.writer.write(out.frame)
            self.done += 1
            if time.monotonic() - self._last_checkpoint >= self.checkpoint_s:
                self._checkpoint()
            self.encode_s += time.perf_counter() - t
            return out

    def _checkpoint(self) -> None:
        """Close the open segment and save the state that names it (atomically: the state is the commit)."""
        if self.writer is None:
            return
        self.writer.close()
        self.segments.append((self.writer.path.name, self.writer.frames))
        self.writer = None
        saved = self.solver.checkpoint() or {}
        saved.update(frames=np.int64(self.done), segments=np.array(json.dumps(self.segments)))
        with atomic_file(self.folder / STATE) as f:
            np.savez(f, **saved)
        self._last_checkpoint = time.monotonic()

    def finish(self, path: Path) -> int:
        """Close the source, checkpoint, and join the segments into ``path``; its frame count."""
        with self._lock:
            self._it.close()
            self._checkpoint()
            return join_segments([self.folder / n for n, _ in self.segments], path, rate=self.rate)

    def stop(self) -> None:
        """After a failure or a cancel: close everything, drop the frames after the last checkpoint."""
        with self._lock:
            self._it.close()
            self._frames.close()
            if self.writer is not None:
                self.writer.abort()
                self.writer.path.unlink(missing_ok=True)
                self.writer = None

    def discard(self) -> None:
        """Remove the run's folder (its asset is in the store)."""
        with self._lock:
            shutil.rmtree(self.folder, ignore_errors=True)


def _source(store: AssetStore, key: str) -> tuple[str, Manifest]:
    """The source asset's id and manifest; a :class:`JobError` for an unknown or unsuitable asset."""
    try:
        aid = store.resolve(key)
        m = store.get(aid)
    except AssetError as exc:
        raise JobError(str(exc)) from exc
    if m.kind == "still":
        raise JobError(f"asset {m.name!r} ({aid[:12]}) is a still image, not a video: compensate an image with "
                       "`shadowless compensate IMAGE_FILE`")
    if m.kind not in ("video", "sequence"):
        raise JobError(f"asset {m.name!r} ({aid[:12]}) is a {m.kind}, not a video")
    if m.channels not in (1, 2, 3, 4) or m.frames < 1:
        raise JobError(f"asset {m.name!r} ({aid[:12]}): {m.channels} channel(s), {m.frames} frame(s): nothing to compensate")
    return aid, m


async def _here(ctx: JobContext, opts: VideoOptions, *, store: AssetStore, src: Manifest, solver: FrameSolver,
                folder: Path, path: Path, rate: Fraction, total: int, stage: str) -> tuple[_Pipeline, int]:
    """Solve frames ``[0, total)`` on this machine into ``path``; the pipeline (its figures) and the frame count."""
    pipe = await ctx.compute(_Pipeline, store, src, solver, folder, rate, predict=opts.psnr,
                             checkpoint_s=opts.checkpoint_s, resume=opts.resume, limit=total,
                             segment=opts.segment_length)
    if pipe.resumed_from:
        ctx.log(f"resuming {src.name!r} from frame {pipe.resumed_from} (a stopped run's checkpoint)")
    ctx.progress(stage, "", pipe.done, total, f"{float(rate):g} fps")
    started = time.monotonic()
    try:
        while pipe.done < total:
            try:
                out = await ctx.compute(pipe.step)
            except CompensationError as exc:
                raise JobError(f"frame {pipe.done}: {exc}") from exc
            if out is None:
                break
            per = (time.monotonic() - started) / (pipe.done - pipe.resumed_from)
            ctx.progress(stage, "", pipe.done, total, f"{1000 * out.seconds:.0f} ms solve, {per:.2f} s/frame, ETA "
                         f"{_duration(per * (total - pipe.done))}", out.objective)
        if pipe.done == 0:
            raise JobError(f"asset {src.name!r}: no frame could be decoded")
        ctx.progress("store", "", 0, 1, path.name)
        await ctx.compute(pipe.finish, path)
    except BaseException:
        await ctx.compute(pipe.stop)   # what was checkpointed stays: the same job run again resumes
        raise
    return pipe, pipe.done


async def run(ctx: JobContext, opts: VideoOptions) -> VideoResult:
    """Compensate every frame of the source asset (warm starts) and store the result as a new asset."""
    t0 = time.monotonic()
    store = AssetStore(ctx.rig.path)
    source_id, src = _source(store, opts.asset)
    if opts.cluster:
        from coordinator.compensation.cluster import import_distributed  # lazy: the `cluster` extra is optional

        import_distributed()   # before anything is measured: a missing extra is a one-line error
    rate = manifest_rate(src)
    total = src.frames if opts.max_frames is None else min(src.frames, opts.max_frames)
    name = opts.name or compensated_name(src.name)
    solver = await open_frame_solver(ctx, camera=opts.camera, measure=opts.measure, level=opts.level,
                                     regularization=opts.regularization, iterations=opts.iterations,
                                     first_iterations=opts.first_iterations, srgb=opts.srgb,
                                     motion=opts.motion)
    work = compensation_dir(ctx.rig) / TMP_DIR
    key = run_key(source_id, solver.transport.meta, opts, solver.size)
    folder = work / (f"{key}-cluster" if opts.cluster else key)   # a cluster run checkpoints per segment
    _sweep(work, folder)
    path = folder / _file_name(name)
    stage = f"compensate {src.name}"
    started = time.monotonic()
    cluster: Figures | None = None
    if opts.cluster:
        from coordinator.compensation.cluster import compensate_on_cluster

        def report(done: int, resumed_from: int, message: str) -> None:
            solved = done - resumed_from
            per = (time.monotonic() - started) / solved if solved > 0 else 0.0
            eta = f", {per:.2f} s/frame, ETA {_duration(per * (total - done))}" if per else ""
            ctx.progress(stage, "", done, total, message + eta)

        ran = await compensate_on_cluster(ctx, opts, store=store, src=src, solver=solver, key=key, folder=folder,
                                          path=path, rate=rate, total=total, report=report)
        if ran.frames == 0:
            raise JobError(f"asset {src.name!r}: no frame could be decoded")
        done, resumed_from, decode_s, encode_s = ran.frames, ran.resumed_from, ran.decode_s, ran.encode_s
        cluster = ran.cluster
        discard = functools.partial(shutil.rmtree, folder, ignore_errors=True)
    else:
        pipe, done = await _here(ctx, opts, store=store, src=src, solver=solver, folder=folder, path=path, rate=rate,
                                 total=total, stage=stage)
        resumed_from, decode_s, encode_s = pipe.resumed_from, pipe.decode_s, pipe.encode_s
        discard = pipe.discard
    try:
        before = {aid for aid, _ in store.list()}
        made = await ctx.compute(store.add, path, name=name, rate=rate)
    except AssetError as exc:
        raise JobError(f"the compensated video could not be stored: {exc}") from exc
    ctx.progress("store", "", 1, 1, made.asset_id[:12])
    await ctx.compute(discard)
    solved = done - resumed_from
    loop_s = time.monotonic() - started
    figures = solver.summary()
    if opts.cluster:
        figures["scale"] = ran.cluster["scale_last_segment"]   # the coordinator's own solver never ran
    note = None
    if done < src.frames:
        note = (f"{done} of the source's {src.frames} frames compensated"
                + (" (max_frames)" if opts.max_frames is not None and done == opts.max_frames else
                   " (the video ended early)"))
    summary = VideoResult(
        source={"id": source_id, "name": src.name, "kind": src.kind, "frames": src.frames,
                "size": [src.width, src.height], "rate": f"{rate.numerator}/{rate.denominator}"},
        asset={"id": made.asset_id, "name": made.name, "frames": made.frames, "size": [made.width, made.height],
               "channels": made.channels, "bit_depth": made.bit_depth, "rate": made.extra.get("rate"),
               "bytes": made.total_bytes, "codec": made.extra.get("codec"), "pix_fmt": made.extra.get("pix_fmt"),
               "already_stored": made.asset_id in before},
        frame_figures=figures, segment_frames=opts.segment_length, resumed_from=resumed_from,
        seconds_per_frame=round(loop_s / solved, 4) if solved else None,
        decode_s=round(decode_s, 3), encode_s=round(encode_s, 3), truncated=done < total, cluster=cluster,
        note=note, wall_s=round(time.monotonic() - t0, 3))
    write_result(ctx.rig, "video.json", summary.to_wire())
    return summary
