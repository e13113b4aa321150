"""Blur compensation numerics for a synthetic-aperture projector rig.

Every projector shows the same image, so the rig's light transport is one matrix
``L = sum_i L_i`` (content pixels -> camera pixels): it is measured with ``S*S`` dot-grid
captures whatever the number of projectors, and compensated with one bounded least-squares
solve ``p' = argmin ||L p - c'||^2, 0 <= p <= 1``. The conventional per-projector method
(``N`` measurements and ``N`` solves) is kept as the baseline.

Modules: :mod:`.response` (luminance response, inverse LUTs, brightness matching),
:mod:`.transport` (dot grids, measurement, storage), :mod:`.solver` (bounded least squares),
:mod:`.quality` (PSNR/SSIM, side-by-side pictures), :mod:`.synthetic` (a synthetic rig for
tests and benchmarks). Functions are pure; long ones take ``progress(iteration, objective)``.
"""
from __future__ import annotations

from .errors import CompensationError, TransportFileError
from .quality import Quality, linear_to_srgb, quality, side_by_side, srgb_to_linear
from .response import (
    BrightnessMatch,
    Linearity,
    Response,
    apply_lut,
    brightness_scale,
    fit_response,
    grey_levels,
    inverse_lut,
    measure_response,
    response_mask,
    verify_linearity,
)
from .solver import (
    FrameCompensator,
    PerProjectorResult,
    SolveResult,
    TransportOperator,
    objective,
    operator_for,
    solve,
    solve_per_projector,
)
from .transport import (
    DotGrid,
    load_transport,
    measure_per_projector,
    measure_transport,
    save_transport,
    transport_error,
    transport_windows,
)

__all__ = [
    "CompensationError",
    "TransportFileError",
    "Quality",
    "quality",
    "side_by_side",
    "srgb_to_linear",
    "linear_to_srgb",
    "Response",
    "Linearity",
    "BrightnessMatch",
    "grey_levels",
    "response_mask",
    "measure_response",
    "fit_response",
    "inverse_lut",
    "apply_lut",
    "verify_linearity",
    "brightness_scale",
    "TransportOperator",
    "FrameCompensator",
    "SolveResult",
    "PerProjectorResult",
    "solve",
    "solve_per_projector",
    "objective",
    "operator_for",
    "DotGrid",
    "measure_transport",
    "measure_per_projector",
    "transport_error",
    "transport_windows",
    "save_transport",
    "load_transport",
]
