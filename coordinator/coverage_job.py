"""The ``coverage`` job: the coverage of an object rig, computed by the coordinator that serves it.

The same computation as `shadowless coverage` (:func:`coordinator.coverage_run.compute_coverage`):
from the slots' 3x4 poses onto the mesh, how many projectors reach each texel and each one's share
of its light, stored under ``coverage/`` with its heat map. As a job it can be started from the
console's Jobs form, whose Pictures panel then shows the heat map and the per-slot table; nothing
is shown on the projectors or captured, so it runs with nodes connected or not.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass

from imaging.calibration.errors import CalibrationError
from coordinator.coverage import DEFAULT_SHADOW_SCALE, DEFAULT_TEXTURE
from coordinator.coverage_run import compute_coverage, view
from coordinator.errors import RigError
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.options import option
from coordinator.jobs.results import Figures, JobResult, spread
from protos.wording import count

__all__ = ["OPTIONS", "CoverageOptions", "CoverageResult", "run"]


def _views(value) -> list[str]:
    """A list of views (``"AZ,EL"`` or ``"camera[:N]"``), each checked."""
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(v, str) for v in items):
        raise ValueError("views must be a list of AZ,EL or camera[:N] strings")
    for v in items:
        try:
            view(v)
        except argparse.ArgumentTypeError as exc:
            raise ValueError(str(exc)) from None
    return list(items)


@dataclass(frozen=True)
class CoverageOptions:
    """How many projectors reach each point of the object (see :mod:`coordinator.coverage_job`)."""

    slots: list[str] | None = option(None, help="only these slots (default: every slot with a 3D pose)")
    planned: bool = option(False, help="the poses a layout planned (rig init --layout) instead of the calibrated ones")
    views: list[str] | None = option(None, parse=_views, metavar="AZ,EL|camera[:N]",
                                     help="viewpoints of the picture (default: from above for a table; "
                                          "front and back, 20 degrees up, for an object)")
    texture: tuple[int, int] = option(DEFAULT_TEXTURE, lo=8, hi=4096, metavar="WxH",
                                      help="texels sampled over the mesh's UV texture")
    shadow_scale: int = option(DEFAULT_SHADOW_SCALE, lo=1, hi=8, metavar="N",
                               help="shadow-map pixels per projector pixel and axis")
    falloff: float = option(1.0, lo=0, hi=10, help="the lenses' fall-off exponent")
    panel: tuple[int, int] = option((480, 480), lo=64, hi=4096, metavar="WxH", help="size of each view")


OPTIONS = CoverageOptions


@dataclass(frozen=True, kw_only=True)
class CoverageResult(JobResult):
    """The ``coverage`` job's result: the coverage's figures (:meth:`coordinator.coverage.Coverage.summary`)
    at the top, then the rig, mesh and poses they are of, when and how fast they were computed, the
    picture, its views and the files written. (The picture's layout stays in the stored file.)"""

    coverage: Figures = spread()
    rig: str
    mesh: str
    poses: str
    computed_at: float
    seconds: float
    picture: str
    views: list[str]
    files: list[str]

    @classmethod
    def from_doc(cls, doc: Figures) -> CoverageResult:
        """The result of :func:`~coordinator.coverage_run.compute_coverage`'s document, its layout left out."""
        named = ("rig", "mesh", "poses", "computed_at", "seconds", "picture", "views", "files")
        return cls(coverage={k: v for k, v in doc.items() if k not in named and k != "layout"},
                   **{k: doc[k] for k in named})


async def run(ctx: JobContext, opts: CoverageOptions) -> CoverageResult:
    steps = iter(range(1, 4))

    def progress(text: str) -> None:
        ctx.progress("coverage", "", next(steps, 3), 3, text)
        ctx.log(text)

    try:
        doc = await ctx.compute(compute_coverage, ctx.rig, slots=opts.slots, planned=opts.planned,
                                views=[view(v) for v in opts.views or []] or None, texture=opts.texture,
                                shadow_scale=opts.shadow_scale, falloff=opts.falloff, panel=opts.panel,
                                progress=progress)
    except (RigError, CalibrationError) as exc:
        raise JobError(" ".join(str(exc).split())) from None
    ctx.progress("coverage", "", 3, 3, "done")
    ctx.log(f"{doc['lit_pct']} % of the surface reached by at least one of {count(doc['slots'], 'projector')}; "
            f"projectors per point: mean {doc['count_mean']}, min {doc['count_min']}; wrote {', '.join(doc['files'])}")
    return CoverageResult.from_doc(doc)     # without the layout: the picture's geometry is for the console's file
