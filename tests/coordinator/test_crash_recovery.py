"""kill -9 of a real coordinator process during every write path it serves (content add through
the real client included), and of `coverage` writing beside it: the next start serves, keeps
every acknowledged write and leaves nothing over. The trial driver is bench/crash.py's (`shadowless bench crash` runs 200 of them)."""
from __future__ import annotations

import asyncio
import hashlib
import signal
import subprocess
import sys

import numpy as np

from bench.crash import PATHS, leftovers, run_trials
from shadowless.local import LocalRig


def test_kill_9_during_every_write_path_leaves_a_rig_that_starts_whole(tmp_path):
    # one trial a path here (the suite's time); `shadowless bench crash --trials 200` runs the many
    rows, _ = run_trials(tmp_path, len(PATHS), seed=7, upload_bytes=4 << 20, max_seconds=240)
    assert len(rows) == len(PATHS), rows
    assert {r["path"] for r in rows} == set(PATHS)
    for r in rows:
        assert r["started"], r
        assert r["lost"] == [] and r["leftovers"] == [] and r["tracebacks"] == 0, r


def test_an_upload_cut_before_its_first_byte_does_not_stop_the_next_start(tmp_path):
    """Issue 35: `begin_upload` and no byte (the client killed), then the coordinator killed: every
    later start failed in the upload sweep. Damage beside it (a truncated announcement, a temp
    file) is settled with one log line each; the same `content add` then completes."""
    rig = LocalRig(["r0c0"], tmp_path, output_size=(64, 48), content_size=(64, 48), mdns=False)
    rig.create()
    clip = tmp_path / "still.npy"
    np.save(clip, np.random.default_rng(1).random((48, 64, 3), dtype=np.float32))
    data = clip.read_bytes()
    try:
        rig.start_coordinator()

        async def announce():
            async with await rig.client(timeout=60) as c:
                return await c.begin_upload([(clip.name, len(data), hashlib.sha256(data).hexdigest())])

        uid, have = asyncio.run(announce())
        assert have == [0]
        other = rig.rig_dir / "assets" / "uploads" / ("b" * 64)
        (other / "files").mkdir(parents=True)
        (other / "spec.json").write_text('{"files": [{"name": "x.png", "si')
        (rig.rig_dir / "slots").mkdir(exist_ok=True)
        (rig.rig_dir / "slots" / ".r0c0.json.k3j4h5g6.tmp").write_text("{")
        rig.coordinator.send_signal(signal.SIGKILL)
        rig.coordinator.wait(30)
        before = len(rig.log("coordinator"))
        rig.start_coordinator()
        rig.wait_ready(60)
        log = rig.log("coordinator")[before:]
        assert "Traceback" not in log, log
        lines = [line for line in log.splitlines() if "start-up recovery:" in line]
        assert len(lines) == 2, lines
        assert any(f"assets/uploads/{'b' * 64}" in line and "rolled back" in line for line in lines), lines
        assert any("slots/.r0c0.json.k3j4h5g6.tmp" in line for line in lines), lines
        assert (rig.rig_dir / "assets" / "uploads" / uid / "files").is_dir()      # the cut upload resumes
        r = subprocess.run([sys.executable, "-m", "shadowless", "content", "add", str(clip), "--coordinator",
                            rig.coordinator_target, "--token-file", str(rig.rig_dir / "token")],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert leftovers(rig.rig_dir) == []
        assert not any((rig.rig_dir / "assets" / "uploads").iterdir())
    finally:
        rig.close()
