"""A benchmark run's working directory: the operator's ``--keep`` folder, or a temporary one
that is removed afterwards, whatever happened (rig directories, logs and generated media of a
256-node run are tens of megabytes)."""
from __future__ import annotations

import contextlib
import shutil
import tempfile
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def run_dir(keep: str | None, name: str) -> Iterator[Path]:
    """``keep/name`` (created, kept) when ``keep`` is given, else a new temporary directory that
    is deleted when the block ends."""
    if keep:
        path = Path(keep) / name
        path.mkdir(parents=True, exist_ok=True)
        yield path
        return
    path = Path(tempfile.mkdtemp(prefix=f"shadowless-{name}-"))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)
