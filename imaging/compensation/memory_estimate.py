"""Memory estimates of the compensation's big allocations, before anything is allocated.

Everything large in blur compensation is a light-transport matrix ``L`` (camera pixels x content
pixels) with one ``(2R+1)^2`` window per content pixel, or something of its size: the arrays it is
recovered or generated from, its transpose, its stencil copy. So the estimates count window entries
``e = n_content * (2R+1)^2`` and give bytes per entry, read off the code and checked against the
peak resident memory of the real work at small sizes (tests/imaging/compensation/test_memory_estimate.py:
each estimate lies between the measured peak and twice it).

* a stored ``L`` (CSR float32, int32 indices): 8 bytes per entry plus its row pointers;
* building one (:func:`~.transport.transport_from_captures`, :func:`~.synthetic.synthetic_transport`):
  the ``(n, K)`` values, rows and valid mask (9 bytes per entry), the masked copies and the CSC to
  CSR conversion: :data:`BUILD_PER_ENTRY` bytes per entry above the result, for a moment;
* an operator for the solver (:class:`~.solver.TransportOperator`): CSR storage adds ``L^T`` (8 bytes
  per entry), the stencil storages a weight image of 4 (float32) or 2 (uint16) bytes per entry;
* a solve: a few dozen float32 images of the content and camera size per channel.

All functions return bytes (``int``) and take sizes in pixels; none allocates.
"""
from __future__ import annotations

__all__ = ["BUILD_PER_ENTRY", "RUNTIME_BYTES", "build_bytes", "entries", "measure_bytes", "operator_bytes",
           "ridge_bytes", "ridge_bytes_of", "solve_bytes", "stored_bytes", "transport_bytes"]

#: bytes per window entry that building one ``L`` holds above the result for a moment (values, rows,
#: valid, masked copies, the CSC arrays while the CSR is made; read off the code: 4 + 4 + 1 + 8 + 8 - 8 = 17,
#: rounded up for numpy's temporaries)
BUILD_PER_ENTRY = 20
#: what the first solve loads besides arrays: the compiled stencil kernels (Numba, LLVM) and thread stacks
RUNTIME_BYTES = 256 << 20
#: float32 images of content / camera size a solve holds per channel (APG's x, y, gradient, previous x,
#: bounds and the products, the start's deconvolution; counted generously)
_SOLVE_IMAGES = 24


def entries(n_content: int, radius: int) -> int:
    """Window entries of an ``L`` over ``n_content`` content pixels at PSF radius ``radius``."""
    if n_content < 0 or radius < 0:
        raise ValueError(f"n_content and radius must be >= 0, got {n_content}, {radius}")
    return int(n_content) * (2 * int(radius) + 1) ** 2


def transport_bytes(n_content: int, n_camera: int, radius: int) -> int:
    """One stored ``L``: CSR float32 data and int32 indices (8 bytes per entry) and its row pointers."""
    return stored_bytes(entries(n_content, radius), n_camera)


def stored_bytes(nnz: int, n_camera: int) -> int:
    """:func:`transport_bytes` of an ``L`` with ``nnz`` entries (e.g. a loaded one's own ``L.nnz``)."""
    return 8 * int(nnz) + (8 if nnz >= 2**31 else 4) * (int(n_camera) + 1)


def build_bytes(n_content: int, n_camera: int, radius: int) -> int:
    """Held for a moment while one ``L`` is recovered from captures or generated, above the result:
    the window arrays, the per-content-pixel geometry and the CSC arrays of the conversion."""
    return BUILD_PER_ENTRY * entries(n_content, radius) + 64 * int(n_content) + 8 * int(n_camera)


def operator_bytes(n_content: int, n_camera: int, radius: int, storage: str = "float32") -> int:
    """What :class:`~.solver.TransportOperator` adds to ``L``: ``L^T`` (``"csr"``) or the weight image
    (``"float32"``, ``"auto"`` on a shared grid: 4 bytes per entry; ``"uint16"``: 2)."""
    e = entries(n_content, radius)
    per = {"csr": 8, "float32": 4, "auto": 4, "uint16": 2}
    if storage not in per:
        raise ValueError(f"storage must be one of {', '.join(per)}, got {storage!r}")
    return per[storage] * e + (4 * int(n_content) if storage == "csr" else 0)


def solve_bytes(n_content: int, n_camera: int, channels: int = 1) -> int:
    """The float32 images one solve holds (per channel, content and camera size)."""
    return 4 * _SOLVE_IMAGES * int(channels) * (int(n_content) + int(n_camera))


def measure_bytes(n_content: int, n_camera: int, radius: int, *, channels: int = 3, held_captures: int = 8) -> int:
    """Peak of measuring one ``L`` from captures (:func:`~.capture_feed.transport_while_capturing`): the
    result, what building it holds for a moment, and ``held_captures`` float32 camera images in flight
    (the feed's queue, the black, the one being averaged)."""
    return (transport_bytes(n_content, n_camera, radius) + build_bytes(n_content, n_camera, radius)
            + 4 * int(channels) * int(n_camera) * int(held_captures))


def ridge_bytes(n_content: int, n_camera: int, radius: int, *, shared_grid: bool = False) -> int:
    """What a :class:`~.ridge.RidgeProblem` adds to a loaded ``L``: an operator for ``L``, the stacked
    ``[L; sqrt(lam) I]`` and its operator, and the copies made on the way. On a real rig the camera and
    content grids differ: CSR operators, ``L^T``, the stack and its transpose held (8 bytes per entry each) and,
    for a moment, the transpose being made and the stack's rows the stencil check slices off (measured: about
    43 bytes per entry); ``shared_grid``: the stencil storages (4 bytes per entry each, about 23 measured)."""
    return ridge_bytes_of(entries(n_content, radius), n_content, n_camera, shared_grid=shared_grid)


def ridge_bytes_of(nnz: int, n_content: int, n_camera: int, *, shared_grid: bool = False) -> int:
    """:func:`ridge_bytes` over an ``L`` with ``nnz`` entries (e.g. a loaded one's own ``L.nnz``)."""
    per = 26 if shared_grid else 48
    return per * int(nnz) + 32 * int(n_content) + 8 * int(n_camera)
