"""The node's renderer: warps content into projector pixels with moderngl (see renderer.py).

The renderer is imported at first use of a name below, not with the package: the node process
imports :mod:`node.render.context` (the ``--gl`` choices) but never draws, and need not hold the
renderer's modules (the presenter process imports them).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

__all__ = ["SPACES", "Mesh", "RenderError", "Renderer"]

if TYPE_CHECKING:  # pragma: no cover
    from node.render.renderer import SPACES, Mesh, RenderError, Renderer


def __getattr__(name: str):
    if name in __all__:
        from node.render import renderer

        return getattr(renderer, name)
    raise AttributeError(f"module 'node.render' has no attribute {name!r}")
