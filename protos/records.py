"""The records a node and the coordinator both speak, defined once.

A node builds them and :mod:`node.wire` turns them into messages; the coordinator's wire module
turns the messages back into the same records. Only records whose shape is the same on both
sides live here: what each side keeps for itself stays in its own package.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass


class DropReason(str, enum.Enum):
    """Why a node did not show a frame (the wire's ``DropReason``)."""

    LATE = "late"                        # arrived, or was rendered, after its presentation time
    SUPERSEDED = "superseded"            # a newer frame was due first
    MISSING_CONTENT = "missing content"  # its content never arrived (or was malformed)
    UNRENDERABLE = "unrenderable"        # the renderer refused it (e.g. content of the wrong size for the pose)
    OTHER = "other"                      # a reason this build does not know (received, never sent)


@dataclass(frozen=True)
class NodeInfo:
    """What a node says about itself when it joins."""

    hostname: str = ""
    pid: int = 0
    host_boot_id: str = ""
    native_size: tuple[int, int] = (0, 0)   # its display's resolution (width, height), (0, 0) when unknown
    software_version: str = ""
    output: str = ""                         # its output kind (offscreen, window, kms, room://…, swarm)
    gl: str = ""                             # what it renders with (see node.presenter.Presenter.gl_info)
