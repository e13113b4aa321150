"""shadowless: many projectors, one synthetic-aperture projector."""

from protos.version import SOFTWARE_VERSION as __version__

__all__ = ["__version__"]
