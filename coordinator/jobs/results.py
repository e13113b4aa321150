"""Typed job results and the one rule that turns them into the JSON a job's caller sees.

Every job's ``run`` returns a frozen dataclass that derives from :class:`JobResult`. Its fields
are the result's keys, in the order they appear on the wire; :meth:`JobResult.to_wire` gives the
plain dict that :func:`coordinator.jobs.registry.run_job` hands to the gRPC edge, the console
and the command line, and that the jobs store in the rig directory. A field declared with
:func:`optional` is left out of that dict while it is None (a key only some runs have, e.g. a
baseline's figures); any other field is always present, None included. A field declared with
:func:`spread` holds a group of figures whose keys stand at the result's own level, where the
field stands (e.g. a light-transport measurement's figures at the top of the ``transport`` job's
result).

Values inside a result may be other :class:`JobResult` dataclasses (turned into dicts the same
way), or dicts, lists, tuples and plain values, passed on as they are (with any result inside them
turned into a dict).
"""
from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["JobResult", "optional", "spread", "to_wire", "Figures"]

#: a nested group of figures whose keys vary with the rig or the run (kept as JSON-able dict)
Figures = dict[str, Any]

_OMIT_NONE = "omit_none"
_SPREAD = "spread"


def optional(default: Any = None) -> Any:
    """A result field left out of :meth:`JobResult.to_wire` while it is None."""
    return dataclasses.field(default=default, metadata={_OMIT_NONE: True})


def spread() -> Any:
    """A result field (a dict or a result) whose keys :meth:`JobResult.to_wire` puts at the result's own level."""
    return dataclasses.field(metadata={_SPREAD: True})


def to_wire(value: Any) -> Any:
    """``value`` with every :class:`JobResult` in it (at any depth of dicts, lists and tuples) turned into
    its dict; everything else as it is."""
    if isinstance(value, JobResult):
        return value.to_wire()
    if isinstance(value, dict):
        return {k: to_wire(v) for k, v in value.items()}
    if isinstance(value, list):
        return [to_wire(v) for v in value]
    if isinstance(value, tuple):
        return tuple(to_wire(v) for v in value)
    return value


@dataclasses.dataclass(frozen=True)
class JobResult:
    """Base of every job's result: a frozen dataclass whose fields are the wire's keys, in order."""

    def to_wire(self) -> dict[str, Any]:
        """The result as the dict the job's callers receive (and the jobs store)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None and f.metadata.get(_OMIT_NONE):
                continue
            if f.metadata.get(_SPREAD):
                out.update(to_wire(value))
            else:
                out[f.name] = to_wire(value)
        return out
