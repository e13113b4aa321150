"""The cue list's hint names the rig the operator typed, so it can be pasted as it is: `shadowless
cue add RIG ...` prints "next: cue 1 (`shadowless cue go RIG`)" with that rig directory (quoted for
the shell), and that command fires the cue. A running coordinator (no nodes needed) and the real
`shadowless cue` processes."""
from __future__ import annotations

import asyncio
import re
import shlex

from coordinator.rig import Rig, grid_slots, init_rig
from protos.auth import read_token
from procs import shadowless_process
from inprocess_coordinator import inprocess_coordinator



def test_the_next_cue_hint_names_the_rig_and_works_as_printed(tmp_path):
    rig = Rig(init_rig(tmp_path / "show rig", name="hints", slots=grid_slots(1, 1), width=32, height=32))

    async def go():
        async with inprocess_coordinator(rig, read_token(rig.path / "token")) as app:
            coordinator = ["--coordinator", f"127.0.0.1:{app.port}"]
            empty = await asyncio.to_thread(shadowless_process, "cue", "list", str(rig.path), *coordinator)
            assert empty.returncode == 0, empty.stderr
            assert f"`shadowless cue add {shlex.quote(str(rig.path))} --kind" in empty.stdout, empty.stdout

            added = await asyncio.to_thread(shadowless_process, "cue", "add", str(rig.path), "--kind", "blackout", "--name", "Preset",
                                            *coordinator)
            assert added.returncode == 0, added.stderr
            hint = re.search(r"next: cue 1 \(`([^`]+)`\)", added.stdout)
            assert hint and hint.group(1) == f"shadowless cue go {shlex.quote(str(rig.path))}", added.stdout

            argv = shlex.split(hint.group(1))      # as a shell splits it; this test has no mDNS: the address
            fired = await asyncio.to_thread(shadowless_process, *argv[1:], *coordinator)
            assert fired.returncode == 0 and "cue 1 'Preset' (blackout) fires" in fired.stdout, fired

    asyncio.run(go())
