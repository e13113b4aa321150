"""`shadowless solo` says which projectors keep the picture and that the others are black: after a
test pattern on every projector it read "solo r0c0: test pattern grid on every projector (4)", as
if every projector still showed it. A running coordinator (no nodes needed) and the real
`shadowless pattern` and `solo` processes."""
from __future__ import annotations

import asyncio

from coordinator.rig import Rig, grid_slots, init_rig
from protos.auth import read_token
from procs import shadowless_process
from inprocess_coordinator import inprocess_coordinator



def test_solo_says_the_others_are_black(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="solo", slots=grid_slots(1, 2), width=32, height=32))

    async def go():
        async with inprocess_coordinator(rig, read_token(rig.path / "token")) as app:
            conn = ["--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", str(rig.path)]
            pattern = await asyncio.to_thread(shadowless_process, "pattern", "grid", *conn)
            assert pattern.returncode == 0 and "test pattern grid on every projector (2)" in pattern.stdout, pattern
            solo = await asyncio.to_thread(shadowless_process, "solo", "r0c1", *conn)
            assert solo.returncode == 0, solo.stderr
            assert solo.stdout.strip() == ("the rig shows solo r0c1, the others black; the picture: test pattern grid on every "
                                           "projector (2)"), solo.stdout
            end = await asyncio.to_thread(shadowless_process, "solo", "--end", *conn)
            assert end.returncode == 0 and end.stdout.strip() == "the rig shows test pattern grid on every projector (2)", end

    asyncio.run(go())
