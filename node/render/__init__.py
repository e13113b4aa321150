"""The node's renderer: warps content into projector pixels with moderngl (see renderer.py)."""
from __future__ import annotations

from node.render.renderer import SPACES, Mesh, RenderError, Renderer

__all__ = ["SPACES", "Mesh", "RenderError", "Renderer"]
