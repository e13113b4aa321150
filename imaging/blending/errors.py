"""Errors of the blending numerics; each message is one line that says what the operator can do."""
from __future__ import annotations

from imaging.errors import ImagingError

__all__ = ["BlendError"]


class BlendError(ImagingError):
    """A blend the numerics cannot produce from the inputs they were given (no projector left, a
    headroom outside 0..0.9, too few samples for a projector); bad shapes raise ``ValueError``."""
