"""The compensation jobs' memory checks: each big step estimated (:mod:`.memory_estimate`) and refused
with one :class:`~coordinator.jobs.JobError` line before it allocates, when it would not fit in what the
coordinator may still take (:mod:`coordinator.memory_budget`)."""
from __future__ import annotations

from imaging.compensation.memory_estimate import (
    BUILD_PER_ENTRY,
    measure_bytes,
    ridge_bytes,
    ridge_bytes_of,
    solve_bytes,
    stored_bytes,
    transport_bytes,
)
from coordinator.jobs.errors import JobError
from coordinator.memory_budget import MemoryBudgetError, ensure_fits

__all__ = ["check_baseline", "check_measure", "check_solve", "check_stored"]

_HINT = "a smaller content size (rig.toml) or camera resolution, or a smaller --radius"


def _fits(estimate: int, what: str, hint: str = _HINT) -> None:
    try:
        ensure_fits(estimate, what=what, hint=f"use {hint}")
    except MemoryBudgetError as exc:
        raise JobError(str(exc)) from None


def _sizes(content: tuple[int, int], camera_shape: tuple[int, ...]) -> tuple[int, int, str]:
    cw, ch = int(content[0]), int(content[1])
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    return cw * ch, hc * wc, f"{cw}x{ch} content seen by a {wc}x{hc} camera"


def check_measure(content: tuple[int, int], camera_shape: tuple[int, ...], radius: int, *, cameras: int = 1) -> None:
    """Before the dot patterns of a light-transport measurement: ``content`` (W, H), ``camera_shape``
    (Hc, Wc[, C]) of the black capture, the PSF ``radius``; ``cameras``: on a mesh each texel has a window
    in each camera (their images stacked), at most that many times the entries."""
    n, m, what = _sizes(content, camera_shape)
    _fits(measure_bytes(n * cameras, m, radius), f"the light transport of {what} (radius {radius})")


def check_baseline(content: tuple[int, int], camera_shape: tuple[int, ...], radius: int, todo: int) -> None:
    """Before measuring ``todo`` projectors' own ``L_i`` (each one is kept for the baseline's solves)."""
    n, m, what = _sizes(content, camera_shape)
    need = todo * transport_bytes(n, m, radius) + measure_bytes(n, m, radius)
    _fits(need, f"{todo} per-projector baseline transports of {what}", f"no --baseline, or {_HINT}")


def check_solve(content: tuple[int, int], camera_shape: tuple[int, ...], radius: int, *, channels: int = 3,
                what: str = "the compensation solve", baselines: int = 0) -> None:
    """Before building a solve's operators over a loaded ``L`` (the ridge problem and its vectors);
    ``baselines``: the per-projector ``L_i`` held beside it (``compensate --baseline``)."""
    n, m, sizes = _sizes(content, camera_shape)
    need = ridge_bytes(n, m, radius) + solve_bytes(n, m + n, channels) + baselines * transport_bytes(n, m, radius)
    if baselines:
        what = f"{what} with {baselines} per-projector baselines"
    _fits(need, f"{what} over {sizes} (radius {radius})", f"no --baseline, or {_HINT}" if baselines else _HINT)


def check_stored(L, *, what: str, baselines: int = 0, solve: bool = True, channels: int = 3) -> None:
    """The same checks from a loaded ``L``'s own non-zeros (a mesh rig's texel windows are not one per content
    pixel): ``baselines`` per-projector ``L_i`` of at most its size (loaded or measured, one being built), and
    with ``solve`` the ridge problem over it, before any of it is allocated."""
    m, n, nnz = int(L.shape[0]), int(L.shape[1]), int(L.nnz)
    need = baselines * stored_bytes(nnz, m)
    if baselines:
        need += BUILD_PER_ENTRY * nnz
    if solve:
        need += ridge_bytes_of(nnz, n, m) + solve_bytes(n, m + n, channels)
    hint = f"no --baseline, or {_HINT}" if baselines else _HINT
    _fits(need, f"{what} over {n} texels seen by {m} camera pixels ({nnz} non-zeros)", hint)
