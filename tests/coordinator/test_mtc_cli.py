"""MIDI timecode from the command line: `coordinator --mtc-port list` and `--mtc-port NAME` refuse in
one line naming the `midi` extra on a coordinator installed without it, and rig.toml's [osc]
mtc_port alone starts show control (it refuses the same way there)."""
from __future__ import annotations

import asyncio
import sys

import pytest

from coordinator.app import CoordinatorApp
from coordinator.osc.mtc_input import MidiUnavailable
from coordinator.rig import Rig, init_rig
from cli_inprocess import run_shadowless


@pytest.fixture
def no_mido(monkeypatch):
    monkeypatch.setitem(sys.modules, "mido", None)      # as on a coordinator installed without [midi]


def test_list_refuses_in_one_line_without_the_extra(tmp_path, capfd, no_mido):
    rig_dir = init_rig(tmp_path / "rig", name="mtc", slots=["a"], width=32, height=32, content_width=64,
                       content_height=32)
    code, out, err = run_shadowless(["coordinator", "--rig", rig_dir, "--mtc-port", "list"], capfd)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and out == "" and len(lines) == 1 and "pip install 'shadowless[midi]'" in lines[0], err


def test_a_coordinator_asked_for_mtc_refuses_to_start_without_the_extra(tmp_path, no_mido):
    rig_dir = init_rig(tmp_path / "rig", name="mtc", slots=["a"], width=32, height=32, content_width=64,
                       content_height=32)

    async def start(**kw):
        app = CoordinatorApp(Rig(rig_dir), b"m" * 32, listen="127.0.0.1:0", advertise=False, **kw)
        with pytest.raises(MidiUnavailable, match=r"shadowless\[midi\]"):
            await app.start()

    asyncio.run(start(mtc_port="desk"))
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nmtc_port = "desk"\n')       # without listen: show control starts for MTC alone
    asyncio.run(start())
