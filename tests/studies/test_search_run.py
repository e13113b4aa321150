"""The search task (the paper's first study) end to end on a real rig: a coordinator and two
offscreen node processes on loopback (real gRPC, real GL). Condition A is r0c0, B is r0c1.
Scripted participants answer each trial after a drawn time waited on the rig clock; every node's
frame is checked against the layout (lit by its condition only, text on the three projected
sheets and grey elsewhere, from an independent numpy reference of the layout's rectangles); the
results file is read by `study paired` for times and for accuracies. The command runs one more
scripted participant and one at the keyboard, refuses an unknown condition without touching the
results, and its help teaches."""
from __future__ import annotations

import asyncio
import csv
import io
import json
from contextlib import redirect_stdout

import cv2
import numpy as np
import pytest
from waits import wait_until

from shadowless.local import LocalRig
from studies import cli as study_cli
from studies.paired import read_measures
from studies.search_log import SearchLog
from studies.search_runner import (ScriptedParticipant, SearchSettings, parse_answer, run_search,
                                   search_schedule)
from studies.search_stimulus import SearchLayout, layout_picture, make_layout, render_content

SLOTS = ["r0c0", "r0c1"]
CONTENT = (120, 80)         # identity poses: content px = projector px
TABLE = (1200.0, 800.0)
CONFIGS = {"A": ("r0c0",), "B": ("r0c1",)}
TIMES = {"A": 0.12, "B": 0.3}


def test_layouts_are_seeded_apart_and_the_content_is_grey_but_for_three_pages():
    a, b = make_layout(11, TABLE), make_layout(12, TABLE)
    assert a == make_layout(11, TABLE) and a != b and SearchLayout.from_json(a.to_json()) == a
    for lay in (a, b):
        assert len(lay.sheets) == 10 and len(lay.projected) == 3 and len(set(lay.projected)) == 3
        for i, s in enumerate(lay.sheets):
            assert 0 <= s.x and s.x + s.w <= TABLE[0] and 0 <= s.y and s.y + s.h <= TABLE[1]
            assert sorted((s.w, s.h)) == [148.0, 210.0]
            for t in lay.sheets[i + 1:]:     # apart: their rectangles do not meet
                assert s.x + s.w <= t.x or t.x + t.w <= s.x or s.y + s.h <= t.y or t.y + t.h <= s.y
    content = render_content(a, (600, 400), grey=0.5)
    assert content.shape == (400, 600, 3) and content.dtype == np.uint16
    grey = round(0.5 * 65535)
    inside = np.zeros((400, 600), bool)
    for k in a.projected:        # mm -> px by hand: x * 600 / 1200, rows from the far edge
        s = a.sheets[k]
        r0, r1 = round((800 - s.y - s.h) / 2), round((800 - s.y) / 2)
        c0, c1 = round(s.x / 2), round((s.x + s.w) / 2)
        inside[r0:r1, c0:c1] = True
        page = content[r0:r1, c0:c1, 0]
        assert page.max() == 65535 and page.min() < 0.7 * 65535 and np.mean(page < 0.9 * 65535) > 0.02   # words
    assert np.all(content[~inside] == grey)
    assert layout_picture(a, 300).shape == (200, 300, 3)
    with pytest.raises(ValueError, match="cannot hold 10 sheets"):
        make_layout(1, (500, 400))
    for bad in ("2 2 5", "1 2", "x y z", "1 2 10"):
        with pytest.raises(ValueError, match="sheet numbers"):
            parse_answer(bad)
    assert parse_answer("7, 2 5") == parse_answer("257") == (2, 5, 7)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = LocalRig(SLOTS, tmp_path_factory.mktemp("searchrig"), output_size=CONTENT, content_size=CONTENT, mdns=False,
                 snapshots=True, latency_ms=100.0)
    with r:
        async def posed():
            async with await r.client(timeout=60) as c:
                await r.wait_live(c, timeout=180)
                for s in SLOTS:
                    await c.configure(s, homography=np.eye(3))

        asyncio.run(posed())
        yield r


class Checked(ScriptedParticipant):
    """A scripted participant that first checks what every node shows for the trial (if ``check``)."""

    def __init__(self, seed, rig, client, check):
        super().__init__(seed, TIMES, miss=0.35)
        self.rig, self.client, self.check, self.checked = rig, client, check, 0

    async def answer(self, prompt, trial, layout, onset_s, rig_now):
        if not self.check:
            return await super().answer(prompt, trial, layout, onset_s, rig_now)
        frame = self.client.last.frame_id
        wait_until(lambda: [json.loads((self.rig.snapshot_dir / f"{s}.json").read_text()).get("frame_id", 0)
                            if (self.rig.snapshot_dir / f"{s}.json").exists() else 0 for s in SLOTS],
                   lambda ids: all(i >= frame for i in ids), what=f"every slot's snapshot of frame {frame}")
        ref = np.round(render_content(layout, CONTENT).astype(np.float32) / 257.0)
        for s in SLOTS:
            shot = cv2.cvtColor(cv2.imread(str(self.rig.snapshot_dir / f"{s}.png")), cv2.COLOR_BGR2RGB).astype(int)
            if s in CONFIGS[trial.condition]:
                assert np.percentile(np.abs(shot - ref), 99) <= 2, (s, trial)
            else:
                assert shot.max() == 0, (s, trial)
        self.checked += 1
        return await super().answer(prompt, trial, layout, onset_s, rig_now)


class Recorded:
    def __init__(self, client):
        self.client, self.last = client, None

    async def show(self, *a, **kw):
        self.last = await self.client.show(*a, **kw)
        return self.last

    def __getattr__(self, name):
        return getattr(self.client, name)


def _paired(path, measure):
    args = study_cli_parser().parse_args(["paired", str(path), "--measure", measure, "--json"])
    out = io.StringIO()
    with redirect_stdout(out):
        assert study_cli.run(args) == 0
    return json.loads(out.getvalue())


def study_cli_parser():
    import argparse

    p = argparse.ArgumentParser(prog="shadowless study")
    study_cli.configure(p)
    return p


def test_scripted_participants_run_the_task_and_study_paired_reads_the_results(rig, tmp_path):
    results = tmp_path / "search.csv"
    settings = SearchSettings(CONTENT, table_mm=TABLE, gap_s=0.0, pictures=tmp_path / "layouts")
    said: list[str] = []
    people = {}

    async def go():
        async with await rig.client(timeout=60) as c:
            rec = Recorded(c)
            for k in (1, 2, 3):
                who = f"scripted:{k}"
                people[who] = Checked(k, rig, rec, check=k == 1)     # one of each condition checked
                trials = search_schedule(who, ["A", "B"], 1, seed=9, order=k)
                assert await run_search(rec, trials, SearchLog(results), CONFIGS, settings, people[who],
                                        say=said.append) == (2, 0)
            again = await run_search(rec, search_schedule("scripted:1", ["A", "B"], 1, seed=9, order=1),
                                     SearchLog(results), CONFIGS, settings, people["scripted:1"], say=said.append)
            return again, (await c.status()).showing

    again, showing = asyncio.run(go())
    assert again == (0, 0) and any("all 2 trials are answered already" in s for s in said) and "black" in showing
    rows = list(csv.DictReader(results.open()))
    assert len(rows) == 6 and sum(p.checked for p in people.values()) == 2
    assert len(list((tmp_path / "layouts").glob("*.png"))) == 6
    for who, person in people.items():
        mine = [r for r in rows if r["participant"] == who]
        assert [r["condition"] for r in mine] == (["A", "B"] if who == "scripted:2" else ["B", "A"])   # orders turn
        for r, (trial, drawn, chosen) in zip(mine, person.drawn):
            projected = tuple(int(v) for v in r["projected"].split())
            assert int(r["trial"]) == trial and make_layout(int(r["seed"]), TABLE).projected == projected
            assert tuple(int(v) for v in r["chosen"].split()) == chosen
            assert float(r["accuracy"]) == pytest.approx(len(set(chosen) & set(projected)) / 3, abs=1e-6)
            # the participant waited its drawn time on the rig clock from the onset before answering
            assert float(r["time_s"]) >= drawn - 1e-3
            assert float(r["answer_s"]) - float(r["onset_s"]) == pytest.approx(float(r["time_s"]), abs=2e-4)
    assert {float(r["accuracy"]) for r in rows} - {1.0}, "the scripted misses never picked a printed sheet"
    times = _paired(results, "time_s")
    assert times["conditions"] == ["B", "A"] and times["n"] == 3 and times["log"] is True
    assert times["mean_difference"] < 0            # A − B: B's drawn times are 2.5 times A's
    times_only = tmp_path / "times.csv"
    times_only.write_text("participant,condition,time_s\n1,A,2\n1,B,3\n2,A,2\n2,B,3\n3,A,2\n3,B,4\n")
    with pytest.raises(ValueError, match="has no accuracy column"):
        read_measures(times_only, "accuracy")
    acc = _paired(results, "accuracy")
    assert acc["measure"] == "accuracy" and acc["test"] == "Wilcoxon signed-rank" and acc["n"] == 3


def test_the_command_runs_a_scripted_participant_and_teaches(rig, tmp_path, monkeypatch):
    (tmp_path / "configs.toml").write_text('[configurations]\nA = ["r0c0"]\nB = ["r0c1"]\n')
    cmd = ["search", "--rig-dir", str(rig.rig_dir), "--coordinator", rig.target, "--participant", "scripted:5",
           "--conditions", "A,B", "--configurations", str(tmp_path / "configs.toml"), "--trials", "1",
           "--scripted-times", "A=0.1,B=0.1", "--gap", "0", "--results", str(tmp_path / "r.csv")]
    out = io.StringIO()
    with redirect_stdout(out):          # in this interpreter: the rig's processes are real, the command's is this one
        assert study_cli.run(study_cli_parser().parse_args(cmd)) == 0
    assert "all 2 trials answered" in out.getvalue()
    rows = list(csv.DictReader((tmp_path / "r.csv").open()))
    assert [r["participant"] for r in rows] == ["scripted:5"] * 2 and {r["condition"] for r in rows} == {"A", "B"}
    # a participant by keyboard: Enter once the sheets are laid out, a mistyped answer is refused and asked
    # again, q (at the next layout) stops with a trial open
    monkeypatch.setattr("sys.stdin", io.StringIO("\nx\n1 2 2\n0 1 2\nq\n"))
    keyboard = [*cmd[:cmd.index("--participant")], "--participant", "4", *cmd[cmd.index("--conditions"):]]
    out = io.StringIO()
    with redirect_stdout(out):
        assert study_cli.run(study_cli_parser().parse_args(keyboard)) == 0
    assert "'x' is not 3 sheet numbers" in out.getvalue() and "'1 2 2' is not 3 different" in out.getvalue()
    assert "stopped with 1 trial(s) open" in out.getvalue()
    rows = list(csv.DictReader((tmp_path / "r.csv").open()))
    assert [(r["participant"], r["chosen"]) for r in rows[2:]] == [("4", "0 1 2")]
    with pytest.raises(SystemExit) as refused:
        study_cli.run(study_cli_parser().parse_args([*cmd[:-2], "--results", str(tmp_path / "r2.csv"),
                                                     "--conditions", "A,C"]))
    assert "condition(s) C are not in" in str(refused.value.code)
    assert not (tmp_path / "r2.csv").exists()
    out = io.StringIO()
    with redirect_stdout(out), pytest.raises(SystemExit):
        study_cli_parser().parse_args(["search", "--help"])
    for taught in ("--participant K|scripted:SEED", "seven carry printed text", "2 5 7", "the rig clock",
                   "study paired RESULTS --measure accuracy", "not rendered in a dry run"):
        assert taught in out.getvalue(), taught
