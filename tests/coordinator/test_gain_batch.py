"""A gain for many slots at once: one batch of file writes (coordinator.rig.Rig.update_slots,
protos.store.atomic_write_files), the files right, a refusal changing nothing, and a process
killed in the middle of batches leaving a rig that opens, each slot old or new."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from coordinator.errors import RigError
from coordinator.rig import HomographyPose, Rig, grid_slots, init_rig
from tests.support.waits import wait_until

SLOTS = grid_slots(5, 5)


def make_rig(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="gains", slots=SLOTS, width=32, height=32, content_width=64,
                       content_height=32)
    rig = Rig(rig_dir)
    ramp = np.linspace(0.0, 1.0, 16, dtype=np.float32)
    for i, s in enumerate(SLOTS):           # every other slot with a LUT: the LUT files go in the batch too
        rig.update_slot(s, pose=HomographyPose(np.eye(3)), lut=np.stack([ramp] * 3) if i % 2 == 0 else None)
    return rig_dir, rig


def slot_docs(rig_dir) -> dict[str, dict]:
    return {s: json.loads((rig_dir / "slots" / f"{s}.json").read_text()) for s in SLOTS}


def test_every_slot_file_holds_the_gain_and_a_refusal_changes_none(tmp_path):
    rig_dir, rig = make_rig(tmp_path)
    before = slot_docs(rig_dir)
    states = rig.update_slots(SLOTS, gain=0.5)
    assert [st.name for st in states] == SLOTS and {st.gain for st in states} == {0.5}
    docs = slot_docs(rig_dir)
    for s in SLOTS:
        assert docs[s]["gain"] == 0.5 and docs[s]["revision"] == before[s]["revision"] + 1
        assert docs[s]["pose"] == before[s]["pose"]
        if "lut" in before[s]:
            assert docs[s]["lut"] == f"luts/{s}.r{docs[s]['revision']}.npy"
            assert sorted(p.name for p in (rig_dir / "luts").glob(f"{s}.r*.npy")) == [f"{s}.r{docs[s]['revision']}.npy"]
    assert not [p for p in (rig_dir / "slots").iterdir() if p.name.startswith(".")], "no temp file left"
    again = Rig(rig_dir)        # what a restarted coordinator reads
    for s in SLOTS:
        assert again.slots[s].gain == 0.5 and again.slots[s].revision == rig.slots[s].revision
        assert (again.slots[s].lut is None) == (rig.slots[s].lut is None)
        if rig.slots[s].lut is not None:
            np.testing.assert_array_equal(again.slots[s].lut, rig.slots[s].lut)

    with pytest.raises(ValueError, match="gain must be in"):
        rig.update_slots(SLOTS, gain=99.0)
    with pytest.raises(RigError, match="not in rig"):
        rig.update_slots([*SLOTS, "nope"], gain=0.25)
    assert slot_docs(rig_dir) == docs and {st.gain for st in rig.slots.values()} == {0.5}


CHILD = textwrap.dedent("""
    import sys
    from coordinator.rig import Rig
    rig = Rig(sys.argv[1])
    names = list(rig.slots)
    i = 0
    while True:
        rig.update_slots(names, gain=0.25 if i % 2 else 0.75)
        i += 1
        if i == 3:
            print("writing", flush=True)
""")


def test_a_process_killed_while_writing_batches_leaves_a_rig_that_opens(tmp_path):
    rig_dir, rig = make_rig(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    for round_ in range(4):
        proc = subprocess.Popen([sys.executable, "-c", CHILD, str(rig_dir)], stdout=subprocess.PIPE, env=env)
        try:
            assert proc.stdout.readline().strip() == b"writing"
            revisions = {s: d["revision"] for s, d in slot_docs(rig_dir).items()}
            # killed at whatever point of a batch it has reached once one more slot file changed
            wait_until(lambda: slot_docs(rig_dir)[SLOTS[12]]["revision"], lambda r: r > revisions[SLOTS[12]],
                       what=f"round {round_}: the writer moving on", timeout=120)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            proc.stdout.close()
        opened = Rig(rig_dir)       # refuses a half-written slot file or a LUT a slot file names but lacks
        assert {st.gain for st in opened.slots.values()} <= {0.25, 0.75, 1.0}
        for i, s in enumerate(SLOTS):
            assert (opened.slots[s].lut is not None) == (i % 2 == 0), s
