"""The ratings file a study run appends to, one answer at a time, so that a crash loses nothing.

Each answer is one CSV line ``participant,first,second,score,image,trial,answer,question``
written with a single ``write`` on a file opened for appending and ``fsync``-ed before the next
question or trial is shown: once the operator sees the next one, the answer is on disk.
``first`` and ``second`` are the configurations on the participant's left and right, ``answer``
what the participant said (-2 clearly left .. 2 clearly right), ``score = -answer`` (positive:
the first, left, one preferred), the form ``shadowless study scheffe`` reads, and ``question``
the key of the question answered (a trial asks every question of the run, each its own line).
With the image column `study scheffe` takes each participant on each image as one judge, with
the question column it analyses each question on its own.

A file from before a run asked two questions (the same columns without ``question``) is still
read by `study scheffe`, but not appended to: a run starts a new file.

A machine that stops in the middle of a write can leave a last line without its newline: it is
cut off when the file is opened again, and that trial is asked again. The file's header is
written once, atomically (a temp file, fsync, rename, fsync of the folder).
"""
from __future__ import annotations

import csv
import io
import os
import tempfile
from pathlib import Path

COLUMNS = ("participant", "first", "second", "score", "image", "trial", "answer", "question")
#: the columns of a ratings file from before a trial asked two questions
LEGACY_COLUMNS = COLUMNS[:-1]


class RatingsLog:
    """An open ratings file: what was answered already, and :meth:`append` for the next answer.

    ValueError (naming the file) when it exists with other columns or a line that is not a rating.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.repaired = 0            # bytes of a torn last line cut off on opening
        if not self.path.exists():
            try:
                self._create()
            except OSError as exc:
                raise ValueError(f"cannot create {self.path}: {exc.strerror or exc}") from None
        self.answered: set[tuple[str, str, str, str, str]] = set()   # (participant, image, first, second, question)
        self._read()

    def _create(self) -> None:
        folder = self.path.parent if str(self.path.parent) else Path(".")
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=folder)
        try:
            with os.fdopen(fd, "w", newline="") as f:
                f.write(",".join(COLUMNS) + "\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        dfd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)

    def _read(self) -> None:
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise ValueError(f"cannot read {self.path}: {exc.strerror or exc}") from None
        if data and not data.endswith(b"\n"):          # a write torn by a crash: its trial is asked again
            keep = data.rfind(b"\n") + 1
            with self.path.open("r+b") as f:
                f.truncate(keep)
                f.flush()
                os.fsync(f.fileno())
            self.repaired, data = len(data) - keep, data[:keep]
        reader = csv.DictReader(io.StringIO(data.decode("utf-8", errors="replace")))
        if reader.fieldnames is not None and "question" not in reader.fieldnames \
                and set(LEGACY_COLUMNS) <= set(reader.fieldnames):
            raise ValueError(f"{self.path}: written before a study run asked two questions per trial (no question "
                             f"column): `study scheffe` still reads it; give the run a new --ratings file")
        if reader.fieldnames is None or not set(COLUMNS) <= set(reader.fieldnames):
            raise ValueError(f"{self.path}: not a study ratings file: its header must name the columns "
                             f"{', '.join(COLUMNS)} (found: {', '.join(reader.fieldnames or []) or 'none'})")
        for k, r in enumerate(reader, start=2):
            if None in r.values() or not r["participant"]:
                raise ValueError(f"{self.path}:{k}: a rating needs every column ({', '.join(COLUMNS)})")
            self.answered.add((r["participant"], r["image"], r["first"], r["second"], r["question"]))

    def has(self, participant: int | str, image: str, left: str, right: str, question: str) -> bool:
        return (str(participant), image, left, right, question) in self.answered

    def append(self, participant: int | str, image: str, left: str, right: str, trial: int, answer: int,
               question: str) -> None:
        """Write one answer (-2 .. 2: clearly left .. clearly right) to ``question`` and fsync it."""
        if answer not in (-2, -1, 0, 1, 2):
            raise ValueError(f"an answer is -2 .. 2, got {answer!r}")
        if not question:
            raise ValueError("an answer names its question")
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow((participant, left, right, -answer, image, trial, answer,
                                                        question))
        data = buf.getvalue().encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        try:
            if os.write(fd, data) != len(data):      # pragma: no cover - a full disk
                raise OSError(f"short write to {self.path}")
            os.fsync(fd)
        finally:
            os.close(fd)
        self.answered.add((str(participant), image, left, right, question))
