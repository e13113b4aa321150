"""A balanced, randomized schedule of side-by-side comparisons: who sees which pair of
configurations on which image, in which order, and which one on the left.

Two designs:

* ``nakaya`` (the default; what ``shadowless study scheffe`` analyses): every participant judges
  every unordered pair of configurations once per image. The side each configuration takes is
  balanced twice over. Within a participant and image every configuration is on the left
  ``(t - 1) / 2`` times (odd ``t``; ``t / 2`` or ``t / 2 - 1`` for even ``t``), from a regular
  tournament (the circulant orientation "i is left of i + d for d = 1 .. (t - 1) / 2", under a
  random relabelling). Across participants every pair is seen each way round equally often:
  participants come in couples, the second of a couple gets the first one's sides reversed
  (an odd last participant leaves each pair one-sided by one view).
* ``ordered``: every ordered pair, so each pair is seen both ways by every participant (the
  design of Scheffé's original method and of Ura's modification; twice the trials).

Trial order is random per participant: shuffled over all images, or (``blocked``) one image
after another, the images' order rotated from participant to participant.
"""
from __future__ import annotations

import csv
import os
import tempfile
from dataclasses import dataclass
from itertools import combinations, permutations
from pathlib import Path
from typing import Sequence

import numpy as np

DESIGNS = ("nakaya", "ordered")
COLUMNS = ("participant", "trial", "image", "left", "right")


@dataclass(frozen=True)
class Trial:
    participant: int      # 1 ..
    trial: int            # 1 .., the order the participant sees them in
    image: str
    left: str             # configuration on the left half
    right: str


def balanced_sides(t: int) -> list[tuple[int, int]]:
    """Every unordered pair of ``range(t)`` once, as (left, right), each item left ``(t - 1) // 2``
    or ``t // 2`` times: i is left of j when ``(j - i) mod t`` is in ``1 .. (t - 1) // 2``, and for
    even ``t`` the opposite pairs (distance ``t / 2``) go to the lower index."""
    out = []
    for i, j in combinations(range(t), 2):
        d = (j - i) % t
        if 2 * d < t or (2 * d == t and i < j):
            out.append((i, j))
        else:
            out.append((j, i))
    return out


def make_schedule(participants: int, configurations: Sequence[str], images: Sequence[str], *,
                  design: str = "nakaya", blocked: bool = False, seed: int | None = None) -> list[Trial]:
    """The trials of ``participants`` people (numbered from 1), every participant's in order."""
    if design not in DESIGNS:
        raise ValueError(f"unknown design {design!r}: choose one of {', '.join(DESIGNS)}")
    configs, images = list(configurations), list(images)
    if len(set(configs)) != len(configs) or len(configs) < 2:
        raise ValueError("need at least 2 different configurations")
    if len(set(images)) != len(images) or not images:
        raise ValueError("need at least one image, each named once")
    if participants < 1:
        raise ValueError("need at least one participant")
    rng = np.random.default_rng(seed)
    t = len(configs)
    trials: list[Trial] = []
    sides: dict[str, list[tuple[int, int]]] = {}
    for p in range(participants):
        per_image: list[list[tuple[str, str, str]]] = []
        for img in images:
            if design == "ordered":
                pairs = list(permutations(range(t), 2))
            elif p % 2 == 0:        # a fresh balanced orientation under a random relabelling
                label = rng.permutation(t)
                pairs = [(int(label[a]), int(label[b])) for a, b in balanced_sides(t)]
                sides[img] = pairs
            else:                   # the couple's second: the same pairs the other way round
                pairs = [(b, a) for a, b in sides[img]]
            order = rng.permutation(len(pairs))
            per_image.append([(img, configs[pairs[k][0]], configs[pairs[k][1]]) for k in order])
        if blocked:
            shift = p % len(images)
            seq = [trial for block in per_image[shift:] + per_image[:shift] for trial in block]
        else:
            flat = [trial for block in per_image for trial in block]
            seq = [flat[k] for k in rng.permutation(len(flat))]
        trials += [Trial(p + 1, k + 1, img, left, right) for k, (img, left, right) in enumerate(seq)]
    return trials


def write_schedule(path: str | Path, trials: Sequence[Trial]) -> None:
    """Write the schedule CSV atomically (a temp file beside it, fsync, rename)."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent or ".")
    try:
        with os.fdopen(fd, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(COLUMNS)
            for tr in trials:
                w.writerow((tr.participant, tr.trial, tr.image, tr.left, tr.right))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_schedule(path: str | Path) -> list[Trial]:
    """A schedule CSV (columns participant, trial, image, left, right). ValueError naming the file
    and line for anything else, or for a participant's trial number given twice."""
    p = Path(path)
    try:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            if not reader.fieldnames or not set(COLUMNS) <= set(reader.fieldnames):
                raise ValueError(f"{p}: the header must name the columns {', '.join(COLUMNS)} "
                                 f"(found: {', '.join(reader.fieldnames or []) or 'none'})")
            out, seen = [], set()
            for k, r in enumerate(reader, start=2):
                try:
                    tr = Trial(int(r["participant"]), int(r["trial"]), r["image"], r["left"], r["right"])
                except (TypeError, ValueError):
                    raise ValueError(f"{p}:{k}: participant and trial must be whole numbers") from None
                if not tr.image or not tr.left or not tr.right or tr.left == tr.right:
                    raise ValueError(f"{p}:{k}: a trial needs an image and two different configurations")
                if (tr.participant, tr.trial) in seen:
                    raise ValueError(f"{p}:{k}: participant {tr.participant} has trial {tr.trial} twice")
                seen.add((tr.participant, tr.trial))
                out.append(tr)
    except OSError as exc:
        raise ValueError(f"cannot read {p}: {exc.strerror or exc}") from None
    return out
