"""Atomic NumPy saves (``.npy``, ``.npz``) on top of :mod:`protos.atomic_files`.

The byte, text, JSON and batch writes, :func:`flocked` and the stale-temp sweep live in
:mod:`protos.atomic_files` (no NumPy, so the node's network process can use them); they are
re-exported here for the modules that import them from ``protos.store``.
"""
from __future__ import annotations

import os

import numpy as np

from protos.atomic_files import (STALE_TEMP_S, atomic_file, atomic_write_bytes, atomic_write_files, atomic_write_json,
                                 atomic_write_text, flocked, fsync_dir, is_temp_name, remove_stale_temps)

__all__ = ["STALE_TEMP_S", "atomic_file", "atomic_save_npy", "atomic_save_npz", "atomic_write_bytes",
           "atomic_write_files", "atomic_write_json", "atomic_write_text", "flocked", "fsync_dir", "is_temp_name",
           "remove_stale_temps"]


def atomic_save_npy(path: str | os.PathLike[str], array: np.ndarray) -> None:
    with atomic_file(path) as f:
        np.save(f, np.asarray(array), allow_pickle=False)


def atomic_save_npz(path: str | os.PathLike[str], **arrays: np.ndarray) -> None:
    with atomic_file(path) as f:
        np.savez(f, **{k: np.asarray(v) for k, v in arrays.items()})
