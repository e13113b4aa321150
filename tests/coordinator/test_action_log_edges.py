"""The action log misses nothing: every `shadowless` command that changes the rig (over gRPC) is an
entry naming who (``token``: the command line logs in with the rig token) and the caller's address,
like the console's and OSC's entries, in the same log the console page shows; a refused command is
an entry too, a call without a session is not; one GO is one entry, whichever edge asked for it
(console, OSC, command line), and an auto-follow's fire is one entry of its own."""
from __future__ import annotations

import asyncio
import socket

import grpc

from coordinator.osc.service import encode
from coordinator.rig import Rig, grid_slots, init_rig
from protos import control_pb2, control_pb2_grpc
from protos.auth import read_token
from protos.cues import Cue, CueList
from cli_inprocess import run_shadowless
from waits import wait_until_async
from action_log import action_log_entries
from inprocess_coordinator import inprocess_coordinator


def test_command_line_calls_are_in_the_action_log_with_who_and_where(tmp_path, capfd):
    rig_dir = init_rig(tmp_path / "rig", name="log", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), read_token(rig_dir / "token"), console="127.0.0.1:0") as app:
            where = ["--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", rig_dir]

            async def cli(*argv):
                return await asyncio.to_thread(run_shadowless, [*argv, *where], capfd)

            app.coordinator.set_cues(CueList((Cue("1", "Dark", "blackout"), Cue("2", "Dark again", "blackout"))))
            for argv in (["blackout"], ["configure", "--slot", "r0c1", "--gain", "0.5"], ["stop"]):
                code, out, err = await cli(*argv)
                assert code == 0, (argv, out, err)
            code, out, err = await cli("configure", "--slot", "nope", "--gain", "0.5")
            assert code != 0, out
            # a call without a session (no token) is refused and is no entry
            async with grpc.aio.insecure_channel(f"127.0.0.1:{app.port}") as ch:
                try:
                    await control_pb2_grpc.RigControlStub(ch).Stop(control_pb2.StopRequest(blackout=True))
                except grpc.aio.AioRpcError as exc:
                    assert exc.code() == grpc.StatusCode.UNAUTHENTICATED
                else:
                    raise AssertionError("a call without a session was served")

            log = await wait_until_async(lambda: action_log_entries(rig_dir), lambda es: len(es) >= 4,
                                         what="four command-line calls in the action log")
            got = [(e["who"], e["address"], e["action"], e["ok"]) for e in log]
            assert got == [("token", "127.0.0.1", "cli blackout", True), ("token", "127.0.0.1", "cli configure", True),
                           ("token", "127.0.0.1", "cli stop", True),
                           ("token", "127.0.0.1", "cli configure", False)], got
            assert log[1]["params"]["slot"] == "r0c1" and "revision" in log[1]["result"]
            assert "nope" in log[3]["result"] and log[0]["result"].startswith("showing black")
            # the console's page shows them: one log per rig directory
            page = app.console.app.audit.recent()
            assert [e["action"] for e in reversed(page)] == [e["action"] for e in log]

    asyncio.run(go())


def test_one_go_is_one_entry_from_the_command_line_osc_and_a_follow(tmp_path, capfd):
    rig_dir = init_rig(tmp_path / "rig", name="go", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\nallow = ["127.0.0.1"]\n')

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), read_token(rig_dir / "token"), console="127.0.0.1:0") as app:
            coord = app.coordinator
            where = ["--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", rig_dir]
            coord.set_cues(CueList((Cue("1", "Dark", "blackout"), Cue("2", "Then", "blackout", follow_s=0.2),
                                    Cue("3", "Last", "blackout"))))
            code, out, err = await asyncio.to_thread(run_shadowless, ["cue", "go", *where], capfd)
            assert code == 0, err
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(encode("/shadowless/go", ()), ("127.0.0.1", app.osc.port))     # cue 2, which follows into 3
            await wait_until_async(lambda: coord.cue_state().current, lambda c: c == 2, what="cue 3 by the follow")
            log = await wait_until_async(lambda: action_log_entries(rig_dir), lambda es: len(es) >= 3,
                                         what="three fires in the action log")
            got = [(e["who"], e["action"], e["params"].get("cue", e["params"].get("id", ""))) for e in log]
            assert got == [("token", "cli cue go", ""), ("osc:127.0.0.1", "osc go", ""),
                           ("follow", "cue fire", "3")], got
            assert log[0]["result"].startswith("cue 1 'Dark' (blackout) fires")
            assert log[1]["result"].startswith("cue 2 'Then' (blackout) fires")
            assert all(e["ok"] for e in log)

    asyncio.run(go())
