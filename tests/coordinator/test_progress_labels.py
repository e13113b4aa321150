"""Real jobs' progress messages label their figures (issue 38: progress lines carried bare
numbers such as ``0.0280468 calibrated`` and ``headroom 29.017``).

A small table rig in the virtual room (in-process, shadowless.room_driver.RoomDriver, as the blend
job's tests run it) is calibrated (multiplexed dots, then sequentially, one projector at a time), its
responses measured and blended; every progress message of the four jobs is read, and so is what
the operator's view (rigctl's ProgressView, as a log) prints of them."""
from __future__ import annotations

import asyncio
import io
import math
import re

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import points_doc
from coordinator.jobs.context import Progress
from rigctl.job_command import ProgressView
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import reference_scene

SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]
#: a number in a message: 12, 0.5, 1e-3, 93%
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?%?")
#: a word naming what follows ("gamma 2.20", "reprojection error 0.31 px") or what precedes ("4 projectors")
WORD = re.compile(r"[A-Za-z][A-Za-z/]*")
#: units a fraction may carry after it
UNITS = {"px", "x", "ms", "s", "dB", "mm", "fps", "s/frame", "Hz", "deg"}


def unlabelled(message: str) -> list[str]:
    """The figures of ``message`` with no label: a percentage is labelled; a whole number, by a word
    right before it (its name: "level 3") or right after it (what it counts: "4 projectors"); a
    fraction, by its name before it ("gamma 2.20", "reprojection error 0.028 px") or a unit after
    it (:data:`UNITS`), never by a bare word after it ("0.0280468 calibrated" is the bug)."""
    bare = []
    for m in NUMBER.finditer(message):
        figure = m.group()
        if figure.endswith("%"):
            continue
        named = m.start() > 0 and message[m.start() - 1] in " :=" and bool(re.search(r"[A-Za-z]\s*[:=]?\s*$", message[:m.start()]))
        after = WORD.match(message[m.end():].lstrip(" ")) if message[m.end():m.end() + 1] == " " else None
        counted = after is not None and ("." not in figure or after.group() in UNITS)
        if not (named or counted):
            bare.append(figure)
    return bare


def test_the_rule_finds_the_bare_figures_of_the_issue():
    assert unlabelled("0.0280468 calibrated") == ["0.0280468"]
    assert unlabelled("3.5") == ["3.5"]
    assert unlabelled("done, 0.4") == ["0.4"]
    assert unlabelled("headroom 1.25 x, 0.5 s/frame, level 3, gamma 2.20") == []
    assert unlabelled("calibrated, reprojection error 0.028 px") == []
    assert unlabelled("4 projectors at once") == [] and unlabelled("headroom 29%, brightness cost 27%") == []


def test_every_progress_message_of_real_jobs_labels_its_figures(tmp_path):
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=1)
    rig = make_rig(tmp_path / "rig", room, SLOTS, content_size=(300, 150))
    driver = RoomDriver(room, rig)
    points = points_doc(table_points_from_truth(room))
    runs = [("calibrate", {"mode": "multiplexed", "settle_s": 0.0, "table_points": points}),
            ("calibrate", {"mode": "sequential", "settle_s": 0.0, "force": True, "slots": SLOTS[:1], "table_points": points}),
            ("response", {"settle_s": 0.0}),
            ("blend", {"settle_s": 0.0})]
    seen: dict[str, list[Progress]] = {}
    for kind, params in runs:
        start = len(driver.events)
        asyncio.run(driver.run(kind, params))
        seen.setdefault(kind, []).extend(e for e in driver.events[start:] if isinstance(e, Progress))

    messages = {(kind, p.stage, p.message) for kind, ps in seen.items() for p in ps}
    bad = sorted((kind, stage, msg, unlabelled(msg)) for kind, stage, msg in messages if unlabelled(msg))
    assert bad == [], bad
    # the figures the issue named are there, labelled
    texts = [m for _, _, m in messages]
    assert any(re.fullmatch(r"calibrated, reprojection error \d+\.\d{3} px", m) for m in texts), texts
    assert any(re.search(r"fitted, gamma \d\.\d\d", m) for m in texts), texts
    assert any(re.fullmatch(r"headroom \d+%, brightness cost \d+%", m) for m in texts), texts
    assert all(re.search(r"headroom \d+(?:\.\d+)?(?:%| x)", m) for m in texts if "headroom" in m), texts
    # figures a job gives as a value for machines: the operator's view prints none of them bare
    with_value = [p for ps in seen.values() for p in ps if not math.isnan(p.value) and p.value != 0]
    assert with_value, "the calibration's error and the response's gamma come as values too"
    log = io.StringIO()
    view = ProgressView(log)
    for ps in seen.values():
        for p in ps:
            view.progress(p)
    view.close()
    printed = log.getvalue()
    for p in with_value:
        assert f"{p.value:.6g} {p.message}" not in printed, p
    for line in printed.splitlines():
        note = line.split("  ")[-1]
        assert not NUMBER.fullmatch(note.strip()), line
