"""The base of every error the numerics raise; each message says what the operator can do.

Bad shapes and dtypes raise ``ValueError``; an ``ImagingError`` is a result the numerics cannot
produce from good inputs (too few points, a singular fit, a damaged transport file), which the
coordinator reports to the operator as it reports its own errors.
"""


class ImagingError(Exception):
    """Base of :class:`~imaging.calibration.errors.CalibrationError` and
    :class:`~imaging.compensation.errors.CompensationError`."""
