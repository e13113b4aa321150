"""The calibration package's exception base."""
from __future__ import annotations

from coordinator.errors import CoordinatorError


class CalibrationError(CoordinatorError):
    """Calibration cannot produce a result; the message says what to check or change."""
