"""Compile the solver's Numba kernels into their cache ahead of use.

``python -m imaging.compensation.precompile`` (``make setup`` runs it): the stencil storage's
kernels (:mod:`.stencil_kernels`) compile on their first call, about 20 s per weight storage
here, and Numba keeps the machine code beside the module for later processes. Run after an
install or an update, the first solve, a video frame or a test does not wait for the compiler;
when the cache is current it only loads it (about a second).

Each storage goes through what a solve does: a small matrix copied into the storage
(``extract_rows``), both products on row views of one and of two channels and the fused sweep
(:func:`.stencil_apg.warm_up`).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from imaging.compensation.stencil import STORAGES, StencilTransport, stencil_from_csr
from imaging.compensation.stencil_apg import warm_up

__all__ = ["main", "precompile"]


def precompile(storage: str) -> float:
    """Compile (or load from the cache) every kernel a solve on ``storage`` uses; returns seconds taken."""
    t = time.perf_counter()
    h, w, r = 12, 8, 1
    csr = StencilTransport((h, w), r, np.full(((2 * r + 1) ** 2, h, w), 0.1, dtype=np.float32)).to_csr()
    if stencil_from_csr(csr, storage=storage, threads=1) is None:
        raise RuntimeError(f"the {storage} storage refused its own test matrix")
    warm_up(storage)
    return time.perf_counter() - t


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m imaging.compensation.precompile",
        description="Compile the blur-compensation solver's kernels into Numba's cache (about 45 s once "
                    "after an install or an update; about a second when the cache is current).")
    parser.add_argument("--storage", choices=STORAGES, action="append",
                        help="weight storage to compile for (repeatable; default: all)")
    args = parser.parse_args(argv)
    for storage in args.storage or STORAGES:
        print(f"solver kernels, {storage} weights: ", end="", flush=True)
        print(f"ready in {precompile(storage):.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
