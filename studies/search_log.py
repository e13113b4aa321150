"""The search task's results file: one CSV line per trial, appended and fsync-ed before the next
trial is shown, so a crash loses nothing and a stopped run resumes.

Columns: ``participant,condition,trial,seed,time_s,accuracy,chosen,projected,frame_id,onset_s,answer_s``.
``time_s`` is the completion time on the rig clock, ``accuracy`` the fraction of the three
projected sheets named (0, 1/3, 2/3 or 1), ``chosen`` and ``projected`` the sheet numbers
(space separated), ``onset_s`` and ``answer_s`` the two rig-clock instants (the coordinator's
uptime, seconds). `shadowless study paired FILE --measure time_s` (or ``accuracy``) reads it as it is.
"""
from __future__ import annotations

import csv
import io
import os
from pathlib import Path

COLUMNS = ("participant", "condition", "trial", "seed", "time_s", "accuracy", "chosen", "projected", "frame_id",
           "onset_s", "answer_s")


class SearchLog:
    """An open results file; ``done`` holds the (participant, condition, trial) already answered.
    ValueError (naming the file) when it exists with other columns."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.done: set[tuple[str, str, int]] = set()
        if not self.path.exists() or self.path.stat().st_size == 0:
            try:
                self._write(",".join(COLUMNS) + "\n")
            except OSError as exc:
                raise ValueError(f"cannot create {self.path}: {exc.strerror or exc}") from None
        data = self.path.read_bytes()
        if not data.endswith(b"\n"):            # torn by a crash: that trial is run again
            keep = data.rfind(b"\n") + 1
            with self.path.open("r+b") as f:
                f.truncate(keep)
            data = data[:keep]
        reader = csv.DictReader(io.StringIO(data.decode("utf-8", errors="replace")))
        if tuple(reader.fieldnames or ()) != COLUMNS:
            raise ValueError(f"{self.path}: not a search results file: its header must be {','.join(COLUMNS)}")
        for r in reader:
            self.done.add((r["participant"], r["condition"], int(r["trial"])))

    def has(self, participant: str, condition: str, trial: int) -> bool:
        return (str(participant), condition, int(trial)) in self.done

    def append(self, participant: str, condition: str, trial: int, seed: int, time_s: float, accuracy: float,
               chosen: tuple[int, ...], projected: tuple[int, ...], frame_id: int, onset_s: float,
               answer_s: float) -> None:
        if not (0.0 <= accuracy <= 1.0) or not time_s > 0:
            raise ValueError(f"time must be positive and accuracy in 0..1, got {time_s!r} and {accuracy!r}")
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow((
            participant, condition, trial, seed, f"{time_s:.4f}", f"{accuracy:.6f}", " ".join(map(str, chosen)),
            " ".join(map(str, projected)), frame_id, f"{onset_s:.4f}", f"{answer_s:.4f}"))
        self._write(buf.getvalue())
        self.done.add((str(participant), condition, int(trial)))

    def _write(self, text: str) -> None:
        data = text.encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            if os.write(fd, data) != len(data):      # pragma: no cover - a full disk
                raise OSError(f"short write to {self.path}")
            os.fsync(fd)
        finally:
            os.close(fd)
