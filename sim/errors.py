"""The one exception base of the sim package and its specific kinds."""
from __future__ import annotations


class SimError(Exception):
    """Base of every error the virtual room raises on purpose."""


class UnknownSlotError(SimError, KeyError):
    """A slot name that is not a projector of this room."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else "unknown slot"


class FrameError(SimError, ValueError):
    """A frame sent to a projector has the wrong size or type."""


class LayoutError(SimError, ValueError):
    """A layout file (TOML) is malformed; the message names the entry."""


class MeshError(SimError, ValueError):
    """A mesh file cannot be read or holds invalid geometry."""


class RenderError(SimError, RuntimeError):
    """The OpenGL (EGL) context the room rasterises meshes with cannot be used."""


class SharedFrameUnavailable(SimError):
    """A node's frames in shared memory cannot be opened here (another host, another user's): the
    node sends them inline instead."""
