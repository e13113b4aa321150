"""Blur compensation for a synthetic-aperture projector rig.

Every projector shows the same image, so the rig's light transport is one matrix
``L = sum_i L_i`` (content pixels -> camera pixels): it is measured with ``S*S`` dot-grid
captures whatever the number of projectors, and compensated with one bounded least-squares
solve ``p' = argmin ||L p - c'||^2, 0 <= p <= 1``. The conventional per-projector method
(``N`` measurements and ``N`` solves) is kept as the baseline.

Numerics (pure functions; long ones take ``progress(iteration, objective)``):
:mod:`.response` (luminance response, inverse LUTs, brightness matching), :mod:`.transport`
(dot grids, recovery from captures, storage format), :mod:`.solver` (bounded least squares),
:mod:`.ridge` (the ridge-regularised problem the jobs solve, warm starts for sequences),
:mod:`.geometry` (content -> camera mapping, PSF radius, dot spacing, target),
:mod:`.patches` (grey patches of the response measurement), :mod:`.quality` (PSNR/SSIM,
side-by-side pictures), :mod:`.quality_figure` (the compensate job's picture: full size, the detail
where the blur costs most enlarged, the error per pixel on one colour scale), :mod:`.synthetic` (a
synthetic rig for tests and benchmarks).

The jobs that run these against a rig (measure, store, push) are in :mod:`coordinator.compensation`.

The names below are loaded on first use, so importing a light submodule (``errors``,
``memory_estimate``) does not load SciPy, OpenCV or scikit-image. (The function ``quality``
is not among them: it shares its name with its module; import it from :mod:`.quality`.)
"""
from __future__ import annotations

import importlib
from typing import Any

#: exported name -> submodule defining it
_EXPORTS = {
    "CompensationError": "errors",
    "TransportFileError": "errors",
    "Quality": "quality",
    "side_by_side": "quality",
    "enlargement": "quality",
    "srgb_to_linear": "quality",
    "linear_to_srgb": "quality",
    "FittedResponse": "response",
    "Linearity": "response",
    "BrightnessMatch": "response",
    "grey_levels": "response",
    "response_mask": "response",
    "capture_means": "response",
    "fit_response": "response",
    "inverse_lut": "response",
    "verify_linearity": "response",
    "brightness_scale": "response",
    "TransportOperator": "solver",
    "FrameCompensator": "solver",
    "SolveResult": "solver",
    "PerProjectorResult": "solver",
    "solve": "solver",
    "solve_per_projector": "solver",
    "objective": "solver",
    "operator_for": "solver",
    "DotGrid": "transport",
    "transport_from_captures": "transport",
    "transports_per_projector": "transport",
    "transport_error": "transport",
    "transport_windows": "transport",
    "save_transport": "transport",
    "load_transport": "transport",
    "RidgeProblem": "ridge",
    "ContentWarmStart": "ridge",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    # lazy re-exports (PEP 562): the submodules import SciPy, OpenCV and scikit-image
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
