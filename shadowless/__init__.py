"""shadowless: many projectors, one synthetic-aperture projector."""

__version__ = "0.1.0"
