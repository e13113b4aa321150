"""The job seam: long work (calibration, response, transport, compensation) runs as jobs
that see only a :class:`JobContext`, backed by a :class:`RigDriver`.

* :mod:`coordinator.jobs.context`: :class:`JobContext` and :class:`Progress`.
* :mod:`coordinator.jobs.driver`: the :class:`RigDriver` protocol.
* :mod:`coordinator.jobs.options`: one definition per job option (validation, CLI, docs).
* :mod:`coordinator.jobs.registry`: which jobs exist, and :func:`~coordinator.jobs.registry.run_job`.
* :mod:`coordinator.jobs.results`: :class:`~coordinator.jobs.results.JobResult`, the base of every
  job's typed result, and the one rule that turns a result into its wire dict.

The option helpers and :class:`JobError` load at once (a command line needs only them); the
context and the driver protocol, which bring the cameras and gRPC along, load on first use.
"""
from __future__ import annotations

from typing import Any

from coordinator.jobs.errors import JobError
from coordinator.jobs.options import add_arguments, option, params_from_args, parse_options

__all__ = ["JobContext", "Progress", "RigDriver", "JobError", "option", "parse_options", "add_arguments",
           "params_from_args"]


def __getattr__(name: str) -> Any:
    if name in ("JobContext", "Progress"):
        from coordinator.jobs import context

        return getattr(context, name)
    if name == "RigDriver":
        from coordinator.jobs import driver

        return driver.RigDriver
    raise AttributeError(f"module 'coordinator.jobs' has no attribute {name!r}")
