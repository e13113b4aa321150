"""`shadowless content add` and `remove` through a running coordinator are entries of the action log
(who: the rig token, the caller's address), done or refused, like every other command-line call that
changes the rig; a refused upload is an entry too."""
from __future__ import annotations

import asyncio

import numpy as np

from coordinator.rig import Rig, grid_slots, init_rig
from node.image_files import write_png
from protos.auth import read_token
from cli_inprocess import run_shadowless
from waits import wait_until_async
from action_log import action_log_entries
from inprocess_coordinator import inprocess_coordinator



def test_content_added_and_removed_from_the_command_line_is_in_the_action_log(tmp_path, capfd):
    rig_dir = init_rig(tmp_path / "rig", name="log", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=64, content_height=32)
    picture = tmp_path / "card.png"
    write_png(picture, np.full((32, 64, 3), 90, np.uint8))
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n not a picture")

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), read_token(rig_dir / "token")) as app:
            where = ["--coordinator", f"127.0.0.1:{app.port}", "--token-file", rig_dir / "token"]

            async def cli(*argv):
                return await asyncio.to_thread(run_shadowless, [*argv, *where], capfd)

            code, out, err = await cli("content", "add", picture, "--name", "card")
            assert code == 0, (out, err)
            code, out, err = await cli("content", "add", broken, "--name", "broken")
            assert code != 0, (out, err)
            code, out, err = await cli("content", "rm", "card")
            assert code == 0, (out, err)
            return await wait_until_async(lambda: action_log_entries(rig_dir), lambda es: len(es) >= 3,
                                          what="three content calls in the action log")

    log = asyncio.run(go())
    got = [(e["who"], e["address"], e["action"], e["ok"]) for e in log]
    assert got == [("token", "127.0.0.1", "cli content add", True), ("token", "127.0.0.1", "cli content add", False),
                   ("token", "127.0.0.1", "cli content remove", True)], got
    assert "added" in log[0]["result"] and log[0]["params"]["name"] == "card"
    assert log[1]["params"]["name"] == "broken" and log[1]["result"]
    assert "removed" in log[2]["result"]
