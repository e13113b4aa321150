"""`shadowless rig`: the coordinator's command (:mod:`rigctl.rigcli`), given the room's builtin meshes.

A layout may name the room's procedural bust (``[mesh] builtin = "bust"``: what ``shadowless plan
--surface bust`` writes). The coordinator does not import the room, so this wiring hands
``rig init --layout`` the mesh the room itself builds for that layout, the very same arrays.
"""
from __future__ import annotations

import argparse

import numpy as np

from rigctl import rigcli

configure = rigcli.configure


def builtin_mesh(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The room's builtin mesh ``name`` as (vertices (V, 3), uvs (V, 2), faces (F, 3)); None if unknown."""
    if name != "bust":
        return None
    # imported only when a layout names it: the room's stack is heavier than the command's
    from sim.mesh import bust

    m = bust()
    return m.vertices, m.uvs, m.faces


def run(args: argparse.Namespace) -> int:
    return rigcli.run(args, builtin_mesh=builtin_mesh)
