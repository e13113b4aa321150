"""``compensate_video --cluster ADDRESS``: the segments of a long video solved on the workers of a
Dask distributed cluster (https://distributed.dask.org), streamed back into one asset.

A show-length video outgrows one machine (10 minutes at 30 fps is 18 000 frames; at ~0.1 s a
frame, half an hour here, far more at 4K). The video is cut into segments of
``--segment-frames`` frames (:func:`~.cluster_segment.segments`, default
:data:`~.options.CLUSTER_SEGMENT_FRAMES`); each is one Dask task
(:func:`~.cluster_segment.solve_segment`) that decodes its own frames, solves them warm-started
from a cold start at its first frame (``first_iterations``, then ``iterations``) and returns its
16-bit FFV1 segment file. A single-machine run with the same ``--segment-frames`` resets its warm
start at the same frames, so both give the same bytes.

What travels, and why:

* ``L`` and the solve's settings (:class:`~.cluster_segment.SegmentSpec`) go to every worker once
  (``client.scatter(..., broadcast=True)``); each worker builds its ridge problem once per run.
* The source goes as bytes, not as a path: a worker need not share the coordinator's disk. A
  video file is scattered once to every worker (it stays in the workers' memory for the run; a
  worker that joins or is restarted fetches it from another); an image sequence's files are sent
  with their segment only. At most ``2 x workers`` segments are in flight, so a long image
  sequence is never held whole.
* Scattered data has no lineage: Dask cannot compute it again, and its active memory manager may
  keep a single replica of it. When the worker holding the last one dies, the segments waiting for
  it are cancelled ("already forgotten"); ``L`` and the source are then scattered again and those
  segments submitted again (:data:`RETRIES` times per segment at most).
* Each result is one message of the segment's encoded frames (about ``N x`` a frame's FFV1 size:
  ~3 MB at 1200x600 RGB), fetched as soon as it is done: lower ``--segment-frames`` for large
  content.

The results arrive in any order (``as_completed``); each is written at once to the run's folder
(``seg-<first frame>.mkv``, then ``segments.json`` naming the finished segments, both atomic: the
checkpoint), and the finished prefix is appended to the output file in order as it grows
(packets copied, :meth:`~.video_io.Ffv1Writer.copy`). A stopped run (cancel, crash) keeps its
finished segments; the same job run again submits only the others. A worker that dies mid-segment
is Dask's to handle: the scheduler runs its task again on another worker (after
``distributed.scheduler.allowed-failures`` deaths it gives up: the job fails and can be resumed);
a task that raises is retried :data:`RETRIES` times. Progress counts frames inside running
segments from the workers' events (:data:`~.cluster_segment.TOPIC`).

``distributed`` is an optional dependency (the ``cluster`` extra): it is imported only here,
when a job asks for a cluster.
"""
from __future__ import annotations

import json
import logging
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

from coordinator.assets import AssetStore
from coordinator.compensation.cluster_segment import (SegmentResult, SegmentSpec, SequenceFrames, segments,
                                                      solve_segment, TOPIC)
from imaging.compensation.errors import CompensationError
from coordinator.compensation.frames import FrameSolver
from coordinator.compensation.options import VideoOptions
from coordinator.compensation.video_io import Ffv1Writer, segment_writer
from coordinator.jobs import JobContext, JobError
from protos.store import atomic_file
from protos.asset_manifest import Manifest

__all__ = ["ClusterRun", "compensate_on_cluster", "import_distributed", "INSTALL"]

log = logging.getLogger(__name__)

#: what installs the cluster support (on the coordinator and on every worker)
INSTALL = "pip install 'shadowless[cluster]'"
STATE = "segments.json"
#: retries of a segment whose task raised (a worker's death is rescheduled by Dask on its own)
RETRIES = 2
CONNECT_S = 20.0
WORKERS_S = 30.0
#: progress lines at most this often (one event arrives per frame solved)
PROGRESS_S = 0.25


def import_distributed() -> Any:
    """The ``distributed`` module; a :class:`JobError` naming the extra when it is not installed."""
    try:
        import distributed
    except ImportError:
        raise JobError(f"--cluster needs Dask distributed on the coordinator: {INSTALL}") from None
    return distributed


@dataclass
class ClusterRun:
    """What a cluster run did: ``frames`` in the output file, ``resumed_from`` of them kept from
    a stopped run, seconds the workers spent decoding and encoding, and the figures of the
    cluster (``cluster``) for the job's summary."""

    frames: int
    resumed_from: int
    decode_s: float
    encode_s: float
    cluster: dict[str, Any] = field(default_factory=dict)


class _Segments:
    """The run's folder: finished segments on disk (the checkpoint) and the output grown in order.

    ``plan`` is every segment ``(start, count)``; ``done`` maps a finished segment's start to its
    figures. :meth:`add` writes a result and appends every segment now in order to the output
    ``path``; a segment shorter than planned (the source ended early) ends the output there. A
    lock makes :meth:`stop` wait for an :meth:`add` in flight (a cancelled job's ``await`` returns
    while its thread still writes).
    """

    def __init__(self, folder: Path, plan: list[tuple[int, int]], path: Path, rate: Fraction, *, resume: bool):
        self.folder, self.plan, self.path, self.rate = folder, plan, path, rate
        self.done: dict[int, dict[str, Any]] = {}
        folder.mkdir(parents=True, exist_ok=True)
        if resume:
            self._load()
        keep = {self._file(s) for s in self.done} | {STATE}
        for f in folder.iterdir():
            if f.name not in keep:
                f.unlink(missing_ok=True)
        self.resumed_from = sum(d["frames"] for d in self.done.values())
        self.writer: Ffv1Writer | None = None
        self.written = 0          # segments of the plan appended to the output
        self.ended = False        # a short segment: the source ended, nothing after it is appended
        self._lock = threading.Lock()

    @staticmethod
    def _file(start: int) -> str:
        return f"seg-{start:08d}.mkv"

    def _load(self) -> None:
        try:
            saved = json.loads((self.folder / STATE).read_text())
            counts = dict(self.plan)
            done = {int(k): v for k, v in saved["segments"].items()}
            if any(counts.get(s) is None or not (0 <= d["frames"] <= counts[s]) or
                   (d["frames"] and not (self.folder / self._file(s)).is_file()) for s, d in done.items()):
                raise ValueError("its segments do not fit this run")
        except FileNotFoundError:
            return
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return                # a damaged checkpoint: every segment again
        self.done = {s: {**d, "resumed": True} for s, d in done.items()}

    def missing(self) -> list[tuple[int, int]]:
        """The segments still to solve, in order."""
        return [(s, c) for s, c in self.plan if s not in self.done]

    @property
    def frames(self) -> int:
        """Frames in finished segments."""
        return sum(d["frames"] for d in self.done.values())

    def add(self, res: SegmentResult) -> None:
        """Keep a finished segment (file, then the state naming it), then grow the output."""
        with self._lock:
            self._add(res)

    def _add(self, res: SegmentResult) -> None:
        if res.frames:
            with atomic_file(self.folder / self._file(res.start)) as f:
                f.write(res.data)
        self.done[res.start] = {"frames": res.frames, "times": res.times, "objectives": res.objectives,
                                "psnrs": [list(p) for p in res.psnrs], "shares": res.shares, "scale": res.scale,
                                "worker": res.worker,
                                "decode_s": res.decode_s, "encode_s": res.encode_s}
        with atomic_file(self.folder / STATE) as f:
            f.write(json.dumps({"segments": self.done}).encode())
        self._assemble()

    def _assemble(self) -> None:
        """Append the finished segments that come next in order to the output file."""
        while not self.ended and self.written < len(self.plan) and self.plan[self.written][0] in self.done:
            start, count = self.plan[self.written]
            frames = self.done[start]["frames"]
            if frames:
                seg = self.folder / self._file(start)
                if self.writer is None:
                    self.writer = segment_writer(seg, self.path, rate=self.rate)
                self.writer.copy(seg)
            self.written += 1
            self.ended = frames < count

    def ordered(self) -> list[dict[str, Any]]:
        """The figures of the segments in the output, in order."""
        return [self.done[s] for s, _ in self.plan[:self.written]]

    def finish(self) -> int:
        """Close the output; its frame count (0 when no segment had a frame)."""
        with self._lock:
            self._assemble()
            if self.writer is None:
                return 0
            self.writer.close()
            return self.writer.frames

    def stop(self) -> None:
        """After a failure or a cancel: drop the half-grown output, keep the finished segments."""
        with self._lock:
            if self.writer is not None:
                self.writer.abort()
                self.writer = None
            self.path.unlink(missing_ok=True)

    def discard(self) -> None:
        """Remove the run's folder (its asset is in the store)."""
        with self._lock:
            shutil.rmtree(self.folder, ignore_errors=True)


def _source_bytes(store: AssetStore, src: Manifest) -> bytes:
    return store.blob_path(src.blobs[0].sha256).read_bytes()


def _sequence_part(store: AssetStore, src: Manifest, start: int, count: int) -> SequenceFrames:
    end = min(start + count, len(src.blobs))
    return SequenceFrames(start, [store.blob_path(b.sha256).read_bytes() for b in src.blobs[start:end]])


async def _a_worker(client: Any, address: str) -> None:
    """Wait for the cluster to have a worker (JobError after :data:`WORKERS_S` seconds)."""
    try:
        await client.wait_for_workers(1, timeout=WORKERS_S)
    except TimeoutError:
        raise JobError(f"the Dask scheduler at {address} has no worker (waited {WORKERS_S:g} s)") from None


def _failure(distributed: Any, start: int, exc: BaseException) -> JobError:
    """The one-line error of a segment that could not be solved."""
    where = f"segment at frame {start}"
    if isinstance(exc, distributed.KilledWorker):
        return JobError(f"{where}: its workers died while solving it, {exc}; run the job again to resume")
    if isinstance(exc, (ModuleNotFoundError, ImportError)):
        return JobError(f"{where}: a worker cannot import shadowless ({exc}): install shadowless[coordinator,cluster] "
                        "where `dask worker` runs, at the coordinator's version")
    if isinstance(exc, CompensationError):
        return JobError(f"{where}: {exc}")
    return JobError(f"{where}: {type(exc).__name__}: {exc}")


class _Progress:
    """Frames done across the run, from finished segments and the workers' per-frame events."""

    def __init__(self, key: str, report: Callable[[int, str], None], finished: int) -> None:
        self.key, self.report, self.finished = key, report, finished
        self.partial: dict[int, int] = {}
        self.workers: dict[int, set[str]] = {}
        self._last = 0.0

    def event(self, event: tuple[float, dict]) -> None:
        msg = event[1]
        if not isinstance(msg, dict) or msg.get("key") != self.key:
            return                # another run's
        start = int(msg["start"])
        self.partial[start] = int(msg["done"])
        self.workers.setdefault(start, set()).add(str(msg["worker"]))
        if time.monotonic() - self._last >= PROGRESS_S:
            self.show()

    def segment_done(self, start: int, frames: int) -> None:
        self.partial.pop(start, None)
        self.finished += frames
        self.show()

    def show(self) -> None:
        self._last = time.monotonic()
        self.report(self.finished + sum(self.partial.values()), f"{len(self.partial)} segment(s) running")

    @property
    def retried(self) -> int:
        """Segments solved on more than one worker (a worker died, or the task raised and was retried)."""
        return sum(1 for w in self.workers.values() if len(w) > 1)


async def compensate_on_cluster(ctx: JobContext, opts: VideoOptions, *, store: AssetStore, src: Manifest,
                                solver: FrameSolver, key: str, folder: Path, path: Path, rate: Fraction, total: int,
                                report: Callable[[int, int, str], None]) -> ClusterRun:
    """Solve frames ``[0, total)`` of ``src`` on the cluster at ``opts.cluster`` into the FFV1 file
    ``path`` (see the module docstring); checkpointed in ``folder``. ``report(done, resumed_from,
    message)`` shows progress (frames done in all, of which kept from a stopped run)."""
    distributed = import_distributed()
    length = int(opts.segment_length or 1)
    segs = await ctx.compute(_Segments, folder, segments(total, length), path, rate, resume=opts.resume)
    todo = segs.missing()
    if segs.done:
        ctx.log(f"resuming {src.name!r}: {len(segs.done)} segment(s), {segs.resumed_from} frames, kept from a stopped "
                "run")
    progress = _Progress(key, lambda done, what: report(done, segs.resumed_from, what), segs.frames)
    workers = 0
    client = None
    running: dict[Any, tuple[int, int, int]] = {}   # future -> (first frame, frames, inputs' generation)
    try:
        if todo:
            try:
                client = await distributed.Client(opts.cluster, asynchronous=True, timeout=CONNECT_S,
                                                  set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                raise JobError(f"cannot reach the Dask scheduler at {opts.cluster}: {exc}") from None
            await _a_worker(client, opts.cluster)
            # asked, not cached: an asynchronous client's scheduler_info() is a cache that distributed may
            # refresh with cluster totals only, whose "workers" is empty
            workers = len((await client.scheduler.identity(n_workers=-1)).get("workers", {}))
            report(segs.frames, segs.resumed_from, f"sending L and the source to {workers} worker(s)")
            spec = SegmentSpec(key=key, transport=solver.transport, regularization=opts.regularization,
                               iterations=opts.iterations, first_iterations=opts.first_iterations, motion=opts.motion,
                               size=solver.size,
                               level=solver.level, region=solver.region, srgb=opts.srgb, predict=opts.psnr,
                               manifest=src, rate=rate)
            sent: dict[str, Any] = {"generation": 0}

            async def send_inputs() -> None:
                """``L`` and the settings (and a video's bytes) to every worker (once one is up again)."""
                await _a_worker(client, opts.cluster)
                sent["spec"] = await client.scatter(spec, broadcast=True, hash=False)
                if src.kind == "video":
                    sent["video"] = await client.scatter(await ctx.compute(_source_bytes, store, src),
                                                         broadcast=True, hash=False)
                sent["generation"] += 1

            await send_inputs()
            client.subscribe_topic(TOPIC, progress.event)
            pending = list(todo)
            flying = distributed.as_completed(loop=client.loop)
            lost: dict[int, int] = {}   # segment -> times its inputs were lost under it

            async def submit() -> None:
                start, count = pending.pop(0)
                part = sent.get("video")
                if part is None:
                    part = await client.scatter(await ctx.compute(_sequence_part, store, src, start, count), hash=False)
                f = client.submit(solve_segment, sent["spec"], part, start, count, retries=RETRIES, pure=False)
                running[f] = (start, count, sent["generation"])
                flying.add(f)

            while pending and len(running) < 2 * max(workers, 1):
                await submit()
            progress.show()
            async for f in flying:
                start, count, generation = running.pop(f)
                try:
                    res = await f
                except distributed.client.FutureCancelledError as exc:   # not ours: its inputs died with a worker
                    lost[start] = lost.get(start, 0) + 1
                    if lost[start] > RETRIES:
                        raise _failure(distributed, start, exc) from exc
                    if generation == sent["generation"]:
                        ctx.log(f"segment at frame {start}: its inputs were lost with a worker ({exc.reason}); "
                                "sending L and the source again")
                        await send_inputs()
                    pending.insert(0, (start, count))
                    await submit()
                    continue
                except Exception as exc:   # the task's own exception, or Dask's (KilledWorker, ...)
                    raise _failure(distributed, start, exc) from exc
                f.release()
                await ctx.compute(segs.add, res)
                progress.segment_done(res.start, res.frames)
                if pending:
                    await submit()
        done = await ctx.compute(segs.finish)
    except BaseException:
        await ctx.compute(segs.stop)
        raise
    finally:
        if client is not None:
            try:
                if running:
                    await client.cancel(list(running))
                client.unsubscribe_topic(TOPIC)
            except Exception as exc:   # a scheduler gone: nothing left to cancel there
                log.warning("video compensation: cancelling the cluster's segments failed: %s", exc)
            await client.close()
    figures = segs.ordered()
    per_worker: dict[str, dict[str, float]] = {}
    for d in figures:
        w = per_worker.setdefault("(earlier run)" if d.get("resumed") else d["worker"], {"segments": 0, "frames": 0, "solve_s": 0.0})
        w["segments"] += 1
        w["frames"] += d["frames"]
        w["solve_s"] = round(w["solve_s"] + sum(d["times"]), 3)
    solver.times = [t for d in figures for t in d["times"]]
    solver.objectives = [v for d in figures for v in d["objectives"]]
    solver.psnrs = [(a, b) for d in figures for a, b in d["psnrs"]]
    solver.shares = [v for d in figures for v in d.get("shares", [])]
    return ClusterRun(frames=done, resumed_from=segs.resumed_from,
                      decode_s=sum(d["decode_s"] for d in figures), encode_s=sum(d["encode_s"] for d in figures),
                      cluster={"address": opts.cluster, "workers": workers, "segment_frames": length,
                               "segments": len(segs.plan), "segments_resumed": len(segs.plan) - len(todo),
                               "segments_retried": progress.retried, "per_worker": per_worker,
                               "scale_last_segment": figures[-1]["scale"] if figures else None})

