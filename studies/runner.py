"""Running one participant's trials on a rig: show each pair of configurations side by side, take
the participant's answer from the operator's keyboard, append it to the ratings file at once.

Every trial goes through the operator API like any show (:meth:`rigctl.link.Client.show`
with per-slot regions): the trial's content is the picture on both halves of the table, and
each slot of the rig is told which halves it lights (the left configuration's slots the left
half, the right one's the right half, slots in both both, every other slot none). Between trials
and before a repeat the rig is black for ``gap_s`` so that a change is seen as one.

Each trial asks every question of the run in turn (by default the two of the paper's second
study, :data:`QUESTIONS`), each answer on disk before the next is asked; ``r`` shows the trial
again and asks the same question again. A question already answered in the ratings file is
not asked again, and a trial whose every question is answered is skipped, so a stopped run
resumes with the same command.
Before each trial the slots the two configurations name must be live with a pose; if one is
not, the operator is told which and may retry or stop.
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from coordinator.api import NodeState
from studies.ratings_log import RatingsLog
from studies.schedule import Trial
from studies.stimulus import compose, slot_regions

ANSWERS = {"-2": -2, "-1": -1, "0": 0, "1": 1, "2": 2, "+1": 1, "+2": 2}
HELP = "-2 clearly left, -1 slightly left, 0 equal, 1 slightly right, 2 clearly right; r repeat, q stop"

#: the questions a trial asks unless told otherwise: (key, the words the operator reads out). The
#: paper's second study asked two questions of every pair, both about the sense of projection: which
#: picture reads more as a pattern of the surface itself (its material), and which reads more as a
#: projected pattern. A lower sense of projection shows as more of the first and less of the second;
#: the two are asked separately because a participant need not answer them as mirror images.
QUESTIONS: tuple[tuple[str, str], ...] = (
    ("intrinsic", "Which side looks more like a pattern of the surface itself, part of its material?"),
    ("projected", "Which side looks more like a projected pattern?"),
)


@dataclass
class RunSettings:
    """How trials look: see :func:`studies.stimulus.compose`; ``gap_s`` of black between them."""

    content_size: tuple[int, int]
    margin: float = 0.05
    surround: float = 0.0
    mirror: bool = False
    gap_s: float = 1.0
    questions: tuple[tuple[str, str], ...] = QUESTIONS
    _composed: dict[str, np.ndarray] = field(default_factory=dict, init=False, repr=False)

    def content(self, image: str, load: Callable[[str], np.ndarray]) -> np.ndarray:
        """The trial content of ``image`` (composed once per image: only the regions change)."""
        if image not in self._composed:
            self._composed[image] = compose(load(image), self.content_size, margin=self.margin,
                                            surround=self.surround, mirror=self.mirror)
        return self._composed[image]


def not_ready(status, slots: Sequence[str]) -> list[str]:
    """The slots of ``slots`` that are not live, or have no pose, in ``status`` (a RigStatus)."""
    nodes = {n.slot: n for n in status.nodes}
    return [s for s in slots if s not in nodes or nodes[s].state != NodeState.LIVE or nodes[s].pose_kind == "none"]


async def run_trials(client, trials: Sequence[Trial], log: RatingsLog, configurations: Mapping[str, Sequence[str]],
                     settings: RunSettings, *, load: Callable[[str], np.ndarray], ask: Callable[[str], str],
                     say: Callable[[str], None] = print) -> tuple[int, int]:
    """Run ``trials`` (one participant's, in order) that ``log`` lacks; returns (answered now, still open).

    ``ask(prompt)`` reads the operator's line, blocking (EOFError counts as ``q``); ``load(name)`` an image.
    """
    def open_questions(t: Trial) -> list[tuple[str, str]]:
        return [(key, text) for key, text in settings.questions if not log.has(t.participant, t.image, t.left, t.right,
                                                                                 key)]

    todo = [t for t in trials if open_questions(t)]
    total, done = len(trials), len(trials) - len(todo)
    if not todo:
        say(f"participant {trials[0].participant}: all {total} trials are answered already")
        return 0, 0
    if done:
        say(f"participant {trials[0].participant}: resuming after {done} of {total} trials answered")
    for key, text in settings.questions:
        say(f"question {key}: {text}")
    rig_slots = [n.slot for n in (await client.status()).nodes]
    answered = 0
    for k, tr in enumerate(todo):
        need = sorted(set(configurations[tr.left]) | set(configurations[tr.right]))
        while missing := not_ready(await client.status(), need):
            line = await _ask(ask, f"slot(s) {', '.join(missing)} not live or without a pose; Enter retries, q stops: ")
            if line.strip().lower() == "q":
                return await _stopped(client, answered, len(todo) - k, say)
        regions = slot_regions(rig_slots, configurations[tr.left], configurations[tr.right], settings.content_size,
                               mirror=settings.mirror)
        content = settings.content(tr.image, load)
        head = f"[{done + k + 1}/{total}] {tr.image}: left {tr.left} | right {tr.right} "
        shown = False
        for key, text in open_questions(tr):
            prompt = f"{head} {key}: {text}  answer ({HELP}): "
            while True:
                if not shown:
                    await _black(client, settings.gap_s)
                    await client.show(content, name=f"study {tr.image}: {tr.left} | {tr.right}", slot_regions=regions)
                    shown = True
                line = (await _ask(ask, prompt)).strip().lower()
                if line == "q":
                    return await _stopped(client, answered, len(todo) - k, say)
                if line == "r":
                    shown = False
                    continue
                if line in ANSWERS:
                    log.append(tr.participant, tr.image, tr.left, tr.right, tr.trial, ANSWERS[line], key)
                    break
                say(f"  {line!r} is not an answer: {HELP}")
        answered += 1
    await client.stop(blackout=True)
    say(f"participant {trials[0].participant}: all {total} trials answered ({answered} now); ratings in {log.path}")
    return answered, 0


async def _ask(ask: Callable[[str], str], prompt: str) -> str:
    """The operator's line, read on the loop's own thread (nothing else runs meanwhile), so that
    Ctrl-C at the prompt interrupts at once; the answers given so far are on disk already."""
    try:
        return ask(prompt)
    except EOFError:
        return "q"


async def _black(client, gap_s: float) -> None:
    if gap_s > 0:
        await client.stop(blackout=True)
        await asyncio.sleep(gap_s)


async def _stopped(client, answered: int, left: int, say: Callable[[str], None]) -> tuple[int, int]:
    await client.stop(blackout=True)
    say(f"stopped with {left} trial(s) open ({answered} answered now); the same command resumes")
    return answered, left
