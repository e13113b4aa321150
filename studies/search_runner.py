"""Running the search task on a rig: one participant's trials, each timed on the rig clock.

A trial: black for ``gap_s``, then the trial's content (:func:`studies.search_stimulus.render_content`)
shown through the operator API (:meth:`rigctl.link.Client.show`), lit only by the slots of the
trial's condition (every other slot black, by per-slot regions). The experimenter's picture of
the layout (sheets numbered 0-9) is written before the trial is shown, and at the keyboard the
experimenter presses Enter once the sheets lie as it shows.

Timing is the rig clock's, never the runner's: the coordinator's status carries its uptime (its
monotonic clock since it started) and, per node, the frame it last swapped and how long ago its
swap report came. The onset is the instant the last of the condition's nodes reported the trial's
frame on screen (uptime − that report's age); the answer's instant is the uptime the status
gives right after the answer is entered. ``time_s`` is their difference. A report comes a little
after its swap, so the onset is late by at most one node report interval and the time short by as
much, the same in both conditions.

The participant types the numbers of the three sheets they chose (e.g. ``2 5 7``), by keyboard
(:class:`Keyboard`), or a script answers (:class:`ScriptedParticipant`, for dry runs). Every trial
is appended to the results file before the next is shown, and a trial already in it is skipped,
so a stopped run resumes with the same command.
"""
from __future__ import annotations

import asyncio
import math
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Awaitable, Callable, Mapping, Sequence

import numpy as np

from coordinator.api import NodeState
from studies.search_log import SearchLog
from studies.search_stimulus import PROJECTED, SHEETS, SearchLayout, layout_picture, make_layout, render_content

HELP = "the three sheet numbers, e.g. 2 5 7; r shows the trial again (its time starts again), q stops"


@dataclass(frozen=True)
class SearchTrial:
    """One trial of one participant: ``trial`` counts from 1 over both conditions; ``seed`` makes its layout."""

    participant: str
    condition: str
    trial: int
    seed: int


def search_schedule(participant: str, conditions: Sequence[str], per_condition: int = 10, *,
                    seed: int = 0, order: int = 0) -> list[SearchTrial]:
    """A participant's trials: ``per_condition`` trials in each condition, in blocks, the block
    order turned by ``order`` (give participants alternate orders to balance them); each trial's
    layout seed is drawn from ``seed`` and the participant, so each participant sees new layouts."""
    if len(conditions) < 1 or per_condition < 1:
        raise ValueError("need at least one condition and one trial per condition")
    k = order % len(conditions)
    blocks = list(conditions[k:]) + list(conditions[:k])
    rng = np.random.default_rng([seed, zlib.crc32(participant.encode())])
    seeds = rng.choice(10 ** 6, size=len(blocks) * per_condition, replace=False).tolist()
    out, n = [], 0
    for c in blocks:
        for _ in range(per_condition):
            out.append(SearchTrial(participant, c, n + 1, int(seeds[n])))
            n += 1
    return out


def parse_answer(line: str, sheets: int = SHEETS, pick: int = PROJECTED) -> tuple[int, ...]:
    """``pick`` distinct sheet numbers 0..sheets-1 from ``line`` (spaces or commas); ValueError in one line."""
    words = [w for w in re.split(r"[\s,]+", line.strip()) if w]
    if len(words) == 1 and words[0].isdigit() and len(words[0]) == pick:   # "257"
        words = list(words[0])
    try:
        nums = tuple(int(w) for w in words)
    except ValueError:
        raise ValueError(f"{line.strip()!r} is not {pick} sheet numbers") from None
    if len(nums) != pick or len(set(nums)) != pick or not all(0 <= n < sheets for n in nums):
        raise ValueError(f"{line.strip()!r} is not {pick} different sheet numbers 0..{sheets - 1}")
    return tuple(sorted(nums))


def accuracy(chosen: Sequence[int], projected: Sequence[int]) -> float:
    """The fraction of the projected sheets among those chosen: 0, 1/3, 2/3 or 1."""
    return len(set(chosen) & set(projected)) / len(projected)


class Keyboard:
    """The experimenter types the participant's answer at this terminal (``ask`` blocks; EOF is q)."""

    def __init__(self, ask: Callable[[str], str] = input):
        self.ask = ask

    async def answer(self, prompt: str, trial: SearchTrial, layout: SearchLayout, onset_s: float,
                     rig_now: Callable[[], Awaitable[float]]) -> str:
        try:
            return self.ask(prompt)
        except EOFError:
            return "q"


class ScriptedParticipant:
    """A participant for dry runs: answers after a time drawn per trial (log-normal around the
    condition's median, ``spread`` its log sd), waited on the rig clock, and names each projected
    sheet correctly, except that with probability ``miss`` it names a printed sheet instead.
    ``drawn`` keeps (trial, seconds, chosen) of every answer given."""

    def __init__(self, seed: int, medians_s: Mapping[str, float], *, spread: float = 0.25, miss: float = 0.1):
        if not 0.0 <= miss <= 1.0 or spread < 0 or any(not v > 0 for v in medians_s.values()):
            raise ValueError("a scripted participant needs medians > 0 s, a spread >= 0 and a miss chance in 0..1")
        self.rng, self.medians, self.spread, self.miss = np.random.default_rng(seed), dict(medians_s), spread, miss
        self.drawn: list[tuple[int, float, tuple[int, ...]]] = []

    async def answer(self, prompt: str, trial: SearchTrial, layout: SearchLayout, onset_s: float,
                     rig_now: Callable[[], Awaitable[float]]) -> str:
        if trial.condition not in self.medians:
            raise ValueError(f"the scripted participant has no time for condition {trial.condition}")
        t = float(self.medians[trial.condition] * math.exp(self.spread * self.rng.standard_normal()))
        printed = [k for k in range(len(layout.sheets)) if k not in layout.projected]
        chosen = []
        for k in layout.projected:
            if printed and self.rng.random() < self.miss:
                chosen.append(printed.pop(int(self.rng.integers(len(printed)))))
            else:
                chosen.append(k)
        while await rig_now() < onset_s + t:
            await asyncio.sleep(0.02)
        self.drawn.append((trial.trial, t, tuple(sorted(chosen))))
        return " ".join(map(str, chosen))


@dataclass
class SearchSettings:
    """How trials look: content ``content_size`` (w, h) over a table of ``table_mm`` (w, d)."""

    content_size: tuple[int, int]
    table_mm: tuple[float, float] = (1200.0, 800.0)
    grey: float = 0.5
    blur_px: float = 0.7
    gap_s: float = 1.0
    pictures: Path | None = None        # where the experimenter's layout pictures go (None: not written)


def _not_ready(status, slots: Sequence[str]) -> list[str]:
    nodes = {n.slot: n for n in status.nodes}
    return [s for s in slots if s not in nodes or nodes[s].state != NodeState.LIVE or nodes[s].pose_kind == "none"]


async def onset(client, frame_id: int, slots: Sequence[str], *, timeout_s: float = 30.0) -> float:
    """The rig-clock instant (coordinator uptime, s) the last of ``slots`` reported ``frame_id`` (or a
    later frame) swapped in; waits for the reports. TimeoutError after ``timeout_s`` of the rig clock."""
    start = None
    while True:
        st = await client.status()
        start = st.uptime_s if start is None else start
        nodes = {n.slot: n for n in st.nodes}
        if all(s in nodes and nodes[s].last_swap_frame >= frame_id and not math.isnan(nodes[s].last_swap_age_ms)
               for s in slots):
            return max(st.uptime_s - nodes[s].last_swap_age_ms / 1e3 for s in slots)
        if st.uptime_s - start > timeout_s:
            raise TimeoutError(f"frame {frame_id} was not reported on screen by {', '.join(slots)} "
                               f"within {timeout_s:g} s")
        await asyncio.sleep(0.02)


async def run_search(client, trials: Sequence[SearchTrial], log: SearchLog,
                     configurations: Mapping[str, Sequence[str]], settings: SearchSettings, participant, *,
                     say: Callable[[str], None] = print) -> tuple[int, int]:
    """Run the trials of ``trials`` that ``log`` lacks, in order; returns (answered now, still open)."""
    todo = [t for t in trials if not log.has(t.participant, t.condition, t.trial)]
    total = len(trials)
    who = trials[0].participant if trials else "?"
    if not todo:
        say(f"participant {who}: all {total} trials are answered already")
        return 0, 0
    if len(todo) < total:
        say(f"participant {who}: resuming after {total - len(todo)} of {total} trials answered")
    rig_slots = [n.slot for n in (await client.status()).nodes]
    w, h = settings.content_size

    async def rig_now() -> float:
        return (await client.status()).uptime_s

    answered = 0
    for k, tr in enumerate(todo):
        need = list(configurations[tr.condition])
        while missing := _not_ready(await client.status(), need):
            ask = getattr(participant, "ask", None)     # a scripted participant has no operator: it stops
            try:
                line = ask(f"slot(s) {', '.join(missing)} not live or without a pose; Enter retries, q stops: ") \
                    if ask else "q"
            except EOFError:
                line = "q"
            if line.strip().lower() == "q":
                return await _stopped(client, answered, len(todo) - k, say, f"slot(s) {', '.join(missing)} not ready")
        layout = make_layout(tr.seed, settings.table_mm)
        content = render_content(layout, settings.content_size, grey=settings.grey, blur_px=settings.blur_px)
        picture = ""
        if settings.pictures is not None:
            import cv2

            settings.pictures.mkdir(parents=True, exist_ok=True)
            path = settings.pictures / f"p{tr.participant}-t{tr.trial:02d}.png"
            cv2.imwrite(str(path), cv2.cvtColor(layout_picture(layout), cv2.COLOR_RGB2BGR))
            picture = f" (layout: {path})"
        regions = {s: ([(0, 0, w, h)] if s in need else []) for s in rig_slots}
        say(f"[{tr.trial}/{total}] {tr.condition}, layout {tr.seed}{picture}: blank sheets on "
            f"{' '.join(map(str, layout.projected))}, printed ones on the others")
        ask = getattr(participant, "ask", None)     # the experimenter lays the sheets out first
        if ask is not None:
            try:
                ready = ask("  lay the sheets out as the picture shows; Enter shows the trial, q stops: ")
            except EOFError:
                ready = "q"
            if ready.strip().lower() == "q":
                return await _stopped(client, answered, len(todo) - k, say, "stopped")
        while True:
            if settings.gap_s > 0:
                await client.stop(blackout=True)
                await asyncio.sleep(settings.gap_s)
            shown = await client.show(content, name=f"search {tr.participant}/{tr.trial} {tr.condition}",
                                      slot_regions=regions)
            t0 = await onset(client, shown.frame_id, need)
            while True:
                line = (await participant.answer(f"  sheets ({HELP}): ", tr, layout, t0, rig_now)).strip().lower()
                t1 = await rig_now()
                if line in ("q", "r"):
                    break
                try:
                    chosen = parse_answer(line, len(layout.sheets), len(layout.projected))
                except ValueError as exc:
                    say(f"  {exc}: {HELP}")
                    continue
                acc = accuracy(chosen, layout.projected)
                log.append(tr.participant, tr.condition, tr.trial, tr.seed, max(t1 - t0, 1e-4), acc, chosen,
                           layout.projected, shown.frame_id, t0, t1)
                say(f"  {t1 - t0:.2f} s, {round(acc * len(layout.projected))} of {len(layout.projected)} right "
                    f"(projected: {' '.join(map(str, layout.projected))})")
                break
            if line == "q":
                return await _stopped(client, answered, len(todo) - k, say, "stopped")
            if line != "r":
                break
        answered += 1
    await client.stop(blackout=True)
    say(f"participant {who}: all {total} trials answered ({answered} now); results in {log.path}")
    return answered, 0


async def _stopped(client, answered: int, left: int, say: Callable[[str], None], why: str) -> tuple[int, int]:
    await client.stop(blackout=True)
    say(f"{why} with {left} trial(s) open ({answered} answered now); the same command resumes")
    return answered, left
