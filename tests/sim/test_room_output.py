"""The node's room output against a real room service on 127.0.0.1."""
from __future__ import annotations

import socket

import pytest
from room_stand_ins import StandInRenderer, info, small_room
from waits import wait_until

from node.outputs import OutputError, open_output
from node.outputs.room_link import RoomOutput
from sim.link import RoomClient
from sim.wire.service import RoomServerThread


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_frames_reach_the_room_and_change_what_the_camera_sees(tmp_path):
    with RoomServerThread(small_room()) as server, RoomClient(server.address) as client:
        out = open_output(f"room://{server.address}", slot="r2c2", snapshot_dir=tmp_path)
        try:
            assert isinstance(out, RoomOutput)
            assert out.native_size() == (160, 100)
            ctx = out.make_context()
            assert ctx.version_code >= 330 and out.make_context() is ctx
            renderer = StandInRenderer(160, 100)
            out.after_swap(renderer.show(0), info(1))
            assert out.flush()
            wait_until(lambda: server.server.service.frames_received, lambda n: n >= 1,
                       what="the room to receive frame 1")
            dark = client.capture()
            assert dark.frames == {"r2c2": (1, dark.frames["r2c2"][1])}
            out.after_swap(renderer.show(255), info(2))
            assert out.flush()
            wait_until(lambda: server.server.service.frames_received, lambda n: n >= 2,
                       what="the room to receive frame 2")
            bright = client.capture()
            assert bright.frames["r2c2"][0] == 2
            assert bright.image.mean() > 10 * dark.image.mean() + 0.005  # one of the 25 units, full white
            assert (tmp_path / "r2c2.png").exists() and (tmp_path / "r2c2.json").exists()
            assert out.frames_dropped == 0 and out.frames_sent == 2
        finally:
            out.close()


def test_a_slow_or_absent_room_costs_dropped_frames_not_waiting_and_the_output_reconnects():
    port = free_port()
    out = RoomOutput(f"room://127.0.0.1:{port}", slot="r2c2", queue_size=2)
    try:
        renderer = StandInRenderer(160, 100)
        for k in range(10):  # nobody listens: the queue keeps the newest two
            out.after_swap(renderer.show(k), info(k))
        assert out.frames_queued == 10
        assert out.frames_dropped >= 5  # at most 2 wait in the queue, a few went to failed streams
        with RoomServerThread(small_room(), port=port) as server, RoomClient(server.address) as client:
            wait_until(lambda: server.server.service.frames_received, lambda n: n >= 1,
                       what="the room to receive a frame")
            assert client.capture().frames["r2c2"][0] == 9  # the newest frame made it
        # The room goes away and comes back (a new process would do the same): the output follows.
        opened = out.streams_opened
        out.after_swap(renderer.show(3), info(10))
        wait_until(lambda: out.streams_opened, lambda n: n > opened, what="the output to try the absent room again")

        def shown() -> tuple:
            """The room's frame id for r2c2, then the output's counters (what a failure shows)."""
            frame_id = client.capture().frames.get("r2c2", (0, 0))[0]
            return frame_id, out.streams_opened, out.frames_sent, out.frames_dropped, out.last_error

        with RoomServerThread(small_room(), port=port) as server, RoomClient(server.address) as client:
            out.after_swap(renderer.show(200), info(11))
            wait_until(shown, lambda seen: seen[0] == 11, what="frame 11 in the room that came back")
        # A room that restarts while the node shows a still frame gets that frame again.
        with RoomServerThread(small_room(), port=port) as server, RoomClient(server.address) as client:
            wait_until(shown, lambda seen: seen[0] == 11, what="frame 11 again in the restarted room")
        assert out.streams_opened >= 3
    finally:
        out.close()


def test_wrong_frame_sizes_are_refused_with_the_expected_size():
    with RoomServerThread(small_room()) as server:
        out = RoomOutput(f"room://{server.address}", slot="r2c2")
        try:
            out.after_swap(StandInRenderer(320, 200), info(1))
            wait_until(lambda: out.last_error, lambda e: e is not None, what="the room's refusal")
            assert "INVALID_ARGUMENT" in out.last_error and "160x100" in out.last_error
        finally:
            out.close()


def test_unknown_slots_and_unreachable_rooms_are_operator_errors():
    with RoomServerThread(small_room()) as server:
        out = RoomOutput(f"room://{server.address}", slot="r9c9")
        try:
            with pytest.raises(OutputError, match="no projector for slot 'r9c9'"):
                out.native_size()
        finally:
            out.close()
    out = RoomOutput(f"room://127.0.0.1:{free_port()}", slot="r0c0", connect_timeout=0.5)
    try:
        with pytest.raises(OutputError, match="shadowless room"):
            out.native_size()
    finally:
        out.close()
    with pytest.raises(OutputError, match="room://HOST:PORT"):
        RoomOutput("room://nohost", slot="r0c0")
