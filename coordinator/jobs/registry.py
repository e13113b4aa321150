"""Which jobs exist, and running one on a rig.

Each job lives in a module of its own that defines ``OPTIONS`` (its option dataclass, see
:mod:`coordinator.jobs.options`) and ``async def run(ctx: JobContext, opts) -> Result``, where
``Result`` is a frozen :class:`~coordinator.jobs.results.JobResult` dataclass; :func:`run_job`
hands its callers the result's :meth:`~coordinator.jobs.results.JobResult.to_wire` dict. It may define ``option_defaults(rig) -> (dict, source)``: values (e.g. a
table of rig.toml) that fill in what a request leaves out, and where they come from. Job modules are imported when a job of their kind first runs, so a
coordinator starts without loading every numerical library.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Awaitable, Callable, Mapping, Sequence

from coordinator.rig import Rig

from coordinator.jobs.context import Event, JobContext
from coordinator.jobs.driver import RigDriver
from coordinator.jobs.errors import JobError
from coordinator.jobs.options import parse_options
from coordinator.jobs.results import JobResult

#: job kind -> module defining OPTIONS and run()
JOBS: dict[str, str] = {
    "calibrate": "coordinator.calibration.calibrate_job",
    "alignment": "coordinator.calibration.alignment_job",
    "response": "coordinator.compensation.response_job",
    "transport": "coordinator.compensation.transport_job",
    "compensate": "coordinator.compensation.compensate_job",
    "compensate_sequence": "coordinator.compensation.sequence_job",
    "compensate_video": "coordinator.compensation.video_job",
    "coverage": "coordinator.coverage_job",
    "blend": "coordinator.blending.blend_job",
}


@dataclass(frozen=True)
class JobSpec:
    kind: str
    options: type
    run: Callable[[JobContext, Any], Awaitable[JobResult]]
    defaults: Callable[[Rig], tuple[Mapping[str, Any], str]] | None = None


def resolve(kind: str) -> JobSpec:
    """The job of ``kind``; a clear error for an unknown kind or a build without its libraries."""
    if kind not in JOBS:
        raise JobError(f"unknown job {kind!r} (known: {', '.join(JOBS)})")
    try:
        mod = importlib.import_module(JOBS[kind])
    except ModuleNotFoundError as exc:
        raise JobError(f"job {kind!r} is not available in this install ({exc.name} missing): "
                       "install shadowless[coordinator]") from exc
    return JobSpec(kind, mod.OPTIONS, mod.run, getattr(mod, "option_defaults", None))


async def run_job(driver: RigDriver, kind: str, params: Mapping[str, Any], *,
                  emit: Callable[[Event], None] | None = None) -> dict:
    """Validate ``params`` against the job's options and run it on ``driver``.

    ``params`` may carry ``cameras`` (a list of camera specs for this run only); the rest must
    be the job's options. Cameras the job opened are closed when it ends, however it ends. Returns the
    job's result as its wire dict (:meth:`JobResult.to_wire`).
    """
    params = dict(params)
    cameras: Sequence[str] | None = params.pop("cameras", None)
    if cameras is not None and (not isinstance(cameras, list) or not all(isinstance(c, str) for c in cameras)):
        raise JobError("cameras must be a list of camera specs")
    spec = resolve(kind)
    defaults, source = spec.defaults(driver.rig) if spec.defaults is not None else ({}, "")
    opts = parse_options(spec.options, params, what=kind, defaults=defaults, defaults_source=source)
    ctx = JobContext(driver, emit=emit, cameras=cameras)
    try:
        result = await spec.run(ctx, opts)
    finally:
        ctx.close()
    if not isinstance(result, JobResult):
        raise TypeError(f"job {kind!r} returned a {type(result).__name__}, not a JobResult")
    return result.to_wire()
