"""Typed job results: the wire dict a result gives its callers (key order, optional keys, spread
figures, results nested in results), and the coverage result built from the stored document."""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import pytest

from coordinator.compensation.baselines import BaselineFigures
from coordinator.compensation.compensate_job import BaselineSolve
from coordinator.compensation.surface import SolveFigures, TransportFigures
from coordinator.compensation.transport_job import TransportResult
from coordinator.coverage_job import CoverageResult
from coordinator.jobs.results import Figures, JobResult, optional, spread


@dataclass(frozen=True, kw_only=True)
class Inner(JobResult):
    a: int
    b: str | None = optional()


@dataclass(frozen=True, kw_only=True)
class Outer(JobResult):
    first: int
    measured: Figures = spread()
    gap: float | None
    inner: Inner
    nested: list[Inner]
    extra: Figures | None = optional()
    last: float


def test_to_wire_keeps_field_order_leaves_out_unset_optional_keys_and_spreads_figures():
    r = Outer(first=1, measured={"m1": 2, "m2": [3]}, gap=None, inner=Inner(a=4), nested=[Inner(a=5, b="x")], last=6.5)
    wire = r.to_wire()
    assert list(wire) == ["first", "m1", "m2", "gap", "inner", "nested", "last"]
    assert wire == {"first": 1, "m1": 2, "m2": [3], "gap": None, "inner": {"a": 4}, "nested": [{"a": 5, "b": "x"}],
                    "last": 6.5}
    with_extra = dataclasses.replace(r, extra={"k": 0}).to_wire()
    assert list(with_extra)[-2:] == ["extra", "last"] and with_extra["extra"] == {"k": 0}
    assert json.loads(json.dumps(wire)) == wire      # plain JSON


def test_results_are_frozen():
    r = Inner(a=1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.a = 2


def test_a_tables_transport_result_has_no_surface_key_and_a_meshs_puts_it_after_the_measurement():
    measurement = {"reused": False, "captures": 19, "radius": 2, "file": "compensation/transport.npz"}
    table = TransportResult(measurement=measurement, figures=TransportFigures(white={"p2": 0.1, "median": 0.2, "max": 0.3}),
                            wall_s=1.5).to_wire()
    assert list(table) == ["reused", "captures", "radius", "file", "white", "wall_s"]
    mesh = TransportResult(measurement=measurement,
                           figures=TransportFigures(surface="mesh", texture={"texels": 4}, white={"median": 0.2},
                                                    visible_surface_pixels=7),
                           baseline={"slots": ["r0c0"]}, wall_s=2.0).to_wire()
    assert list(mesh) == ["reused", "captures", "radius", "file", "surface", "texture", "white",
                          "visible_surface_pixels", "baseline", "wall_s"]


def test_solve_figures_of_a_table_and_of_a_mesh():
    common = dict(method="apg", iterations=12, reason="tol", converged=True, penalised_objective=0.5,
                  regularization=0.02, gap=None, seconds=0.1, lipschitz=3.0)
    table = SolveFigures(objective=0.4, initial_objective=0.9, **common).to_wire()
    assert list(table) == ["method", "iterations", "reason", "converged", "objective", "initial_objective",
                           "penalised_objective", "regularization", "gap", "seconds", "lipschitz"]
    mesh = SolveFigures(rows=100, columns=50, **common).to_wire()
    assert list(mesh) == ["method", "iterations", "reason", "converged", "penalised_objective", "regularization",
                          "gap", "seconds", "lipschitz", "rows", "columns"]
    assert mesh["gap"] is None            # a figure that is None stays on the wire


def test_coverage_result_is_the_stored_document_without_its_layout():
    doc = {"texture": [64, 64], "slots": 2, "lit_pct": 97.5, "per_slot": {"a": {}}, "rig": "r", "mesh": "m",
           "poses": "calibrated", "computed_at": 1.0, "seconds": 0.5, "picture": "p.png", "views": ["az 0 el 90"],
           "layout": {"panels": []}, "files": ["c.npz", "c.json", "p.png"]}
    wire = CoverageResult.from_doc(doc).to_wire()
    assert wire == {k: v for k, v in doc.items() if k != "layout"}
    assert list(wire) == [k for k in doc if k != "layout"]


def test_a_compensate_results_baseline_puts_its_measurement_before_its_solves():
    measured = BaselineFigures(slots=["r0c0", "r0c1"], excluded=["r0c2"], measured=["r0c1"], captures=50,
                               captures_per_projector=25, frames=1, exposure=1.0, seconds=3.2)
    wire = BaselineSolve(measurement=measured, solve_seconds=0.4, iterations=60, solve_seconds_sum=0.35).to_wire()
    assert list(wire) == ["slots", "excluded", "measured", "captures", "captures_per_projector", "frames", "exposure",
                          "seconds", "solve_seconds", "iterations", "solve_seconds_sum"]
    assert wire["excluded"] == ["r0c2"] and wire["iterations"] == 60
