"""A study run on a real rig: a coordinator and three offscreen node processes on loopback (real
gRPC, real GL). Configuration A is r0c0 + r0c1, B is r0c1 alone, r0c2 is in neither; each trial
shows A and B side by side, so r0c0 must light one half only, r0c1 both, r0c2 nothing. What
every node rendered (its snapshot) is compared with an independent reference: the trial content
masked with numpy and warped with OpenCV. The operator's keyboard is a script: a wrong key, a
repeat, an answer to each of two questions, a stop, then the same run again resumes at the open
trial; a trial stopped between its two questions asks only the open one."""
from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys

import cv2
import numpy as np
import pytest
from waits import wait_until

from rigctl.client import CallRefused
from studies.configurations import load_configurations
from studies.ratings_log import RatingsLog
from studies.runner import RunSettings, run_trials
from studies.schedule import make_schedule
from studies.stimulus import compose
from shadowless.local import LocalRig

SLOTS = ["r0c0", "r0c1", "r0c2"]
OUT, CONTENT = (64, 48), (80, 40)       # llvmpipe nodes share two cores: small outputs
CONFIGS = '[configurations]\nA = ["r0c0", "r0c1"]\nB = ["r0c1"]\n'


def homography(i: int) -> np.ndarray:
    """Content px -> projector px, a different one per slot."""
    return np.array([[0.7, 0.02 * i, 3.0 + i], [0.01 * i, 0.95, 4.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = LocalRig(SLOTS, tmp_path_factory.mktemp("studyrig"), output_size=OUT, content_size=CONTENT, mdns=False,
                 snapshots=True, latency_ms=100.0)
    with r:
        async def posed():
            async with await r.client(timeout=60) as c:
                await r.wait_live(c, timeout=180)
                for i, s in enumerate(SLOTS):
                    await c.configure(s, homography=homography(i))

        asyncio.run(posed())
        yield r


class Recorded:
    """The real client, remembering the frame id of its last show."""

    def __init__(self, client):
        self.client, self.last = client, None

    async def show(self, *a, **kw):
        self.last = await self.client.show(*a, **kw)
        return self.last

    def __getattr__(self, name):
        return getattr(self.client, name)


def snapshot_frame_ids(rig) -> dict[str, int]:
    """The frame id of each slot's last snapshot (0: none yet)."""
    ids = {}
    for s in SLOTS:
        try:
            ids[s] = json.loads((rig.snapshot_dir / f"{s}.json").read_text()).get("frame_id", 0)
        except (OSError, ValueError):   # not written yet, or caught between two writes
            ids[s] = 0
    return ids


def wait_snapshots(rig, frame_id: int) -> dict[str, np.ndarray]:
    """Every slot's snapshot, once each shows frame ``frame_id`` or a later one."""
    wait_until(lambda: snapshot_frame_ids(rig), lambda ids: all(i >= frame_id for i in ids.values()),
               what=f"a snapshot of frame {frame_id} from every slot")
    return {s: cv2.cvtColor(cv2.imread(str(rig.snapshot_dir / f"{s}.png")), cv2.COLOR_BGR2RGB) for s in SLOTS}


def reference(content_u16: np.ndarray, keep_columns: list[slice], h: np.ndarray) -> np.ndarray:
    """The content with everything outside ``keep_columns`` black, warped as a node does."""
    f = content_u16.astype(np.float32) / 65535.0
    masked = np.zeros_like(f)
    for cols in keep_columns:
        masked[:, cols] = f[:, cols]
    warped = cv2.warpPerspective(masked, h, OUT, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return np.round(np.clip(warped, 0, 1) * 255).astype(np.uint8)


def test_trials_light_each_half_with_its_configuration_and_resume(rig, tmp_path):
    card = np.zeros((20, 20, 3), np.uint8)
    card[..., 0] = np.linspace(30, 250, 20, dtype=np.uint8)[None, :]
    card[..., 1] = np.linspace(250, 30, 20, dtype=np.uint8)[:, None]
    card[5:15, 5:15, 2] = 200
    configs_file = tmp_path / "configs.toml"
    configs_file.write_text(CONFIGS)
    configs = load_configurations(configs_file)
    trials = make_schedule(1, ["A", "B"], ["card"], design="ordered", seed=0)     # A|B and B|A
    settings = RunSettings(CONTENT, margin=0.0, surround=0.2, gap_s=0.0,
                           questions=(("sop", "Which looks painted on?"), ("shadow", "Which shadow disturbs less?")))
    content = compose(card, CONTENT, margin=0.0, surround=0.2)
    half = {"left": slice(0, CONTENT[0] // 2), "right": slice(CONTENT[0] // 2, CONTENT[0])}
    log = RatingsLog(tmp_path / "ratings.csv")
    said: list[str] = []
    checked: list[tuple[str, str]] = []
    asked: list[str] = []

    def checker(client, script):
        def ask(prompt: str) -> str:
            left, right = re.search(r"left (\S+) \| right (\S+) ", prompt).groups()
            asked.append(re.search(r" (sop|shadow): ", prompt).group(1))
            shots = wait_snapshots(rig, client.last.frame_id)
            for i, s in enumerate(SLOTS):
                cols = [half[side] for side, cfg in (("left", left), ("right", right)) if s in configs[cfg]]
                diff = np.abs(shots[s].astype(int) - reference(content, cols, homography(i)).astype(int))[1:-1, 1:-1]
                assert np.percentile(diff, 99) <= 2 and diff.mean() < 0.3, (s, left, right, diff.max(), diff.mean())
            lit = {s: int(shots[s].max()) for s in SLOTS}
            assert lit["r0c0"] > 100 and lit["r0c1"] > 100 and lit["r0c2"] == 0, lit
            checked.append((left, right))
            return script.pop(0)
        return ask

    async def go():
        async with await rig.client(timeout=60) as c:
            await rig.wait_live(c, timeout=180)
            # the operator API refuses regions it cannot honour, naming what is wrong
            for kw, says in (({"slot_regions": {"r9c9": []}}, "'r9c9', which is not a slot"),
                             ({"slot_regions": {"r0c0": []}, "persist": True}, "not persisted")):
                with pytest.raises(CallRefused) as refused:
                    await c.show(content, **kw)
                assert refused.value.code == "INVALID_ARGUMENT" and says in refused.value.details
            rec = Recorded(c)
            first = await run_trials(rec, trials, log, configs, settings, load=lambda name: card,
                                     ask=checker(rec, ["x", "r", "2", "0", "1", "q"]), say=said.append)
            again = await run_trials(rec, trials, RatingsLog(log.path), configs, settings, load=lambda name: card,
                                     ask=checker(rec, ["-1"]), say=said.append)
            showing = (await c.status()).showing
        return first, again, showing

    first, again, showing = asyncio.run(go())
    assert first == (1, 1) and again == (1, 0)
    (l1, r1), (l2, r2) = (trials[0].left, trials[0].right), (trials[1].left, trials[1].right)
    # trial 1 shown, its sop asked again after 'x' was refused and 'r' asked for a repeat, then its shadow;
    # trial 2's sop answered, a stop before its shadow, which the second run asks alone
    assert checked == [(l1, r1)] * 4 + [(l2, r2)] * 3
    assert asked == ["sop", "sop", "sop", "shadow", "sop", "shadow", "shadow"]
    assert any("'x' is not an answer" in s for s in said) and any("resuming after 1 of 2" in s for s in said)
    rows = log.path.read_text().splitlines()
    assert rows[1:] == [f"1,{l1},{r1},-2,card,1,2,sop", f"1,{l1},{r1},0,card,1,0,shadow",
                        f"1,{l2},{r2},-1,card,2,1,sop", f"1,{l2},{r2},1,card,2,-1,shadow"]
    assert "black" in showing


def test_the_command_runs_a_participant_from_the_keyboard(rig, tmp_path):
    """`shadowless study schedule`, then `shadowless study run` in a process of its own, the answers
    typed on its standard input; a second run finds nothing open."""
    (tmp_path / "configs.toml").write_text(CONFIGS)
    for name in ("one.png", "two.png"):
        cv2.imwrite(str(tmp_path / name), np.full((30, 40, 3), 180, np.uint8))
    base = [sys.executable, "-m", "shadowless", "study"]
    env = {**os.environ, "LP_NUM_THREADS": "1"}
    done = subprocess.run([*base, "schedule", "--participants", "2", "--images", "one.png,two.png", "--configurations",
                           str(tmp_path / "configs.toml"), "--seed", "5", "-o", str(tmp_path / "s.csv")],
                          capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0, done.stderr
    assert "2 participant(s) x 2 trials (2 configurations, 2 image(s), design nakaya, seed 5)" in done.stderr
    run = [*base, "run", str(tmp_path / "s.csv"), "--participant", "2", "--ratings", str(tmp_path / "r.csv"),
           "--configurations", str(tmp_path / "configs.toml"), "--gap", "0", "--rig-dir", str(rig.rig_dir),
           "--coordinator", rig.target]
    done = subprocess.run(run, input="7\n1\n2\n-2\n0\n", capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    assert "'7' is not an answer" in done.stdout and "all 2 trials answered" in done.stdout
    rows = (tmp_path / "r.csv").read_text().splitlines()
    assert len(rows) == 5 and [r.split(",")[6] for r in rows[1:]] == ["1", "2", "-2", "0"]
    assert [r.split(",")[7] for r in rows[1:]] == ["intrinsic", "projected"] * 2   # the default two questions
    assert {r.split(",")[4] for r in rows[1:]} == {"one.png", "two.png"}
    again = subprocess.run(run, input="", capture_output=True, text=True, timeout=120, env=env)
    assert again.returncode == 0 and "all 2 trials are answered already" in again.stdout, again.stderr
