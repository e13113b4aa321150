"""The seam between the compensation jobs and the kind of surface a rig projects on.

A rig's projectors light a table (every slot with a homography pose: content pixels map to the
camera through one homography) or an object (every slot with a 3x4 pose: the content is the
mesh's texture, seen through the mesh rendered from the camera). The ``transport`` and
``compensate`` jobs each have one body; what differs between the two surfaces is a
:class:`Surface`: :class:`~coordinator.compensation.planar_surface.PlanarSurface` or
:class:`~coordinator.compensation.mesh_surface.MeshSurface`, chosen by
:func:`~coordinator.compensation.surfaces.surface_for`. A surface measures (or reuses) the light
transport ``L`` and the per-projector baseline's ``L_i``, states the figures of a measurement,
builds the target and solves for an image (a :class:`Solution`), solves the baseline, and scores
captures for the evaluation (a :class:`~coordinator.compensation.evaluation.Scoring`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import scipy.sparse as sp

from coordinator.jobs import JobError
from coordinator.jobs.results import Figures, JobResult, optional

if TYPE_CHECKING:
    from coordinator.compensation.baselines import BaselineFigures
    from coordinator.compensation.evaluation import Scoring
    from coordinator.compensation.options import CompensateOptions, TransportOptions
    from coordinator.compensation.store import StoredTransport
    from coordinator.jobs import JobContext

__all__ = ["Surface", "Solution", "SolveFigures", "TransportFigures", "Baselines", "nonempty"]

#: the per-projector ``L_i`` by slot, and the figures of their measurement
Baselines = tuple[dict[str, sp.csr_matrix], "BaselineFigures"]


@dataclass(frozen=True, kw_only=True)
class TransportFigures(JobResult):
    """What the ``transport`` job reports of a measurement beyond its stored figures: the rig's white
    (``L 1``: 2nd percentile, median, maximum) where content is scored; on a mesh also the surface's
    name, how much of the texture the measurement covers and the visible surface's pixels."""

    surface: str | None = optional()
    texture: Figures | None = optional()
    white: Figures
    visible_surface_pixels: int | None = optional()


@dataclass(frozen=True, kw_only=True)
class SolveFigures(JobResult):
    """The ``solve`` figures of a ``compensate`` result. The objectives of the data term alone
    (``objective``, ``initial_objective``) are a table's; the problem's rows and columns a mesh's."""

    method: str
    iterations: int
    reason: str
    converged: bool
    objective: float | None = optional()
    initial_objective: float | None = optional()
    penalised_objective: float
    regularization: float
    gap: float | None
    seconds: float
    lipschitz: float | None
    rows: int | None = optional()
    columns: int | None = optional()


@dataclass(frozen=True, kw_only=True)
class Solution:
    """A compensated image and the figures of its solve, as a :class:`Surface` made them.

    ``tr`` is the light transport it was solved over; ``x`` and ``none`` are (H, W, C) float32 in 0..1 at the rig's content size: ours, and the content
    scaled to the target without compensation (``none_scale``). Each surface derives its own class,
    carrying what its baseline and its evaluation need.
    """

    tr: StoredTransport
    x: np.ndarray
    none: np.ndarray
    none_scale: float
    seconds: float                  #: the solve's own time (the baseline's is compared with it)
    target_level: float
    target_level_from: str
    solve: SolveFigures
    texture: Figures | None = None
    weights: str | None = None
    saturated_fraction: Figures


class Surface(Protocol):
    """What the ``transport`` and ``compensate`` jobs need from a kind of surface."""

    #: "table" or "mesh"
    kind: str
    #: the image solve's default ridge weight on this surface
    regularization: float
    #: what a persisted result says of where it went
    shown_note: str

    def refuse(self, opts: TransportOptions) -> None:
        """A :class:`JobError` for options this surface cannot take."""

    async def transport(self, ctx: JobContext, opts: TransportOptions, slots: list[str], *,
                        measure: bool = True) -> StoredTransport:
        """The stored ``L`` while it is valid, else a new measurement (``measure=False``: a JobError)."""

    async def baselines(self, ctx: JobContext, tr: StoredTransport, opts: TransportOptions) -> Baselines:
        """Each projector's ``L_i`` (stored ones reused, the rest measured), those that add no light left out."""

    async def transport_figures(self, ctx: JobContext, tr: StoredTransport) -> TransportFigures:
        """The ``transport`` job's figures of a measurement beyond :func:`~.store.transport_summary`."""

    def check_solve(self, tr: StoredTransport, content_size: tuple[int, int], opts: CompensateOptions) -> None:
        """Refuse a solve (with its baselines) that would not fit in memory, before anything is built."""

    async def solve(self, ctx: JobContext, tr: StoredTransport, content: np.ndarray,
                    opts: CompensateOptions) -> Solution:
        """The compensated image of ``content`` ((H, W, C) float32, the rig's content size)."""

    async def solution_baselines(self, ctx: JobContext, sol: Solution, opts: CompensateOptions) -> Baselines:
        """The baseline's ``L_i`` for a solution (measured now, or already while solving)."""

    async def solve_baselines(self, ctx: JobContext, sol: Solution, base_L: dict[str, sp.csr_matrix],
                              opts: CompensateOptions) -> tuple[dict[str, np.ndarray], list]:
        """The conventional method's image per projector ((H, W, C) float32, by slot) and its solves."""

    async def scoring(self, ctx: JobContext, sol: Solution, opts: CompensateOptions) -> Scoring:
        """How the evaluation captures and scores this solution."""


def nonempty(found: Baselines) -> Baselines:
    """``found`` unless no projector adds light (then a JobError)."""
    if not found[0]:
        raise JobError("baseline: no projector adds light to the camera image")
    return found
