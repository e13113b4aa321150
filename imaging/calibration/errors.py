"""The exception base of calibration's numerics and jobs."""
from __future__ import annotations

from imaging.errors import ImagingError


class CalibrationError(ImagingError):
    """Calibration cannot produce a result; the message says what to check or change."""
