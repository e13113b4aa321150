"""Frames a node leaves in shared memory for the room (room.proto's SharedFrame): a node process's
frames reach the room without their pixels crossing the socket, the camera sees exactly what was
shown, a frame overwritten before the room read it is skipped for the newer one, and a room that
cannot open the memory (here: one in a PID namespace of its own, as on another host) makes the node
send its frames inline."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import grpc
import numpy as np
import pytest
from room_stand_ins import StandInRenderer, info, small_room
from waits import wait_until

from node.outputs.frame_ring import FrameRing
from node.outputs.room_link import RoomOutput
from protos import room_pb2, room_pb2_grpc
from sim.link import RoomClient
from sim.wire.service import RoomServerThread

ROOT = Path(__file__).resolve().parents[2]

#: a node's room output in a process of its own: one frame of value 0, then on each line read from
#: stdin one frame of that value, each flushed before "sent N" is printed
NODE = r"""
import itertools, sys, time
import numpy as np
from node.outputs import SwapInfo
from node.outputs.room_link import RoomOutput

class Frame:
    def __init__(self, w, h): self.buffer = np.zeros((h, w, 3), np.uint8)
    def read(self): return self.buffer

address, slot = sys.argv[1], sys.argv[2]
out = RoomOutput(f"room://{address}", slot=slot)
w, h = out.native_size()
frame = Frame(w, h)
for k, line in enumerate(itertools.chain(["0"], sys.stdin), start=1):
    frame.buffer[:] = int(line)
    now = time.monotonic_ns()
    out.after_swap(frame, SwapInfo(slot=slot, frame_id=k, tag=f"show-{k}", pts_ns=now, swap_rig_ns=now, host_monotonic_ns=now))
    assert out.flush()
    print("sent", k, out.shares_frames, flush=True)
out.close()
"""


def test_a_node_process_frames_reach_the_room_through_shared_memory_exactly():
    with RoomServerThread(small_room()) as server, RoomClient(server.address) as client:
        service = server.server.service
        node = subprocess.Popen([sys.executable, "-c", NODE, server.address, "r2c2"], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            assert node.stdout.readline().split() == ["sent", "1", "True"]
            wait_until(lambda: service.frames_received, lambda n: n >= 1, what="the room to take frame 1")
            dark = client.capture()
            node.stdin.write("255\n")
            node.stdin.flush()
            assert node.stdout.readline().split() == ["sent", "2", "True"]
            wait_until(lambda: service.frames_received, lambda n: n >= 2, what="the room to take frame 2")
            bright = client.capture()
            shown = server.server.service.room.frame("r2c2")      # what the projector shows since that capture
        finally:
            node.stdin.close()
            assert node.wait(timeout=60) == 0
        # both frames came through the node's memory, none inline, and the camera saw each one
        assert (service.frames_shared, service.frames_received, service.frames_overwritten) == (2, 2, 0)
        assert dark.frames["r2c2"][0] == 1 and bright.frames["r2c2"][0] == 2
        assert bright.image.mean() > 10 * dark.image.mean() + 0.005
        assert shown.shape == (100, 160, 3) and (shown == 255).all()


def test_the_room_shows_exactly_the_shared_pixels_as_it_shows_inline_ones():
    rng = np.random.default_rng(3)
    picture = rng.integers(0, 256, (100, 160, 3), dtype=np.uint8)
    captures = {}
    for share in (True, False):
        with RoomServerThread(small_room()) as server, RoomClient(server.address) as client:
            out = RoomOutput(f"room://{server.address}", slot="r2c2", share_frames=share)
            try:
                frame = StandInRenderer(160, 100)
                frame.buffer[:] = picture
                out.after_swap(frame, info(1))
                assert out.flush()
                wait_until(lambda: server.server.service.frames_received, lambda n: n >= 1, what="frame 1 in the room")
                assert server.server.service.frames_shared == (1 if share else 0)
                captures[share] = client.capture().image
                np.testing.assert_array_equal(out.last_image, picture)
            finally:
                out.close()
    np.testing.assert_array_equal(captures[True], captures[False])


def _stream(address: str, messages: list) -> grpc.RpcError | room_pb2.DisplayAck:
    with grpc.insecure_channel(address) as channel:
        try:
            return room_pb2_grpc.RoomStub(channel).Display(iter(messages), timeout=30)
        except grpc.RpcError as exc:
            return exc


def _shared(ring: FrameRing, offset: int, seq: int, frame_id: int, slot: str = "r2c2") -> room_pb2.DisplayedFrame:
    h, w = ring.shape[:2]
    now = time.monotonic_ns()
    return room_pb2.DisplayedFrame(slot=slot, frame_id=frame_id, swap_rig_ns=now, host_monotonic_ns=now, tag="show",
                                   shared=room_pb2.SharedFrame(pid=ring.pid, fd=ring.fd, offset=offset, seq=seq, width=w, height=h))


def test_a_frame_overwritten_before_the_room_read_it_is_skipped_for_the_newer_one():
    ring = FrameRing((100, 160, 3), label="r2c2", count=2)
    try:
        with RoomServerThread(small_room()) as server, RoomClient(server.address) as client:
            first = ring.write(np.full((100, 160, 3), 255, np.uint8))
            ring.write(np.zeros((100, 160, 3), np.uint8))
            newest = ring.write(np.full((100, 160, 3), 40, np.uint8))     # the first frame's buffer again
            ack = _stream(server.address, [_shared(ring, *first, frame_id=1), _shared(ring, *newest, frame_id=3)])
            assert isinstance(ack, room_pb2.DisplayAck) and ack.frames == 1
            service = server.server.service
            assert (service.frames_overwritten, service.frames_shared) == (1, 1)
            assert client.capture().frames["r2c2"][0] == 3
    finally:
        ring.close()


def test_memory_the_room_cannot_or_must_not_open_is_refused_as_a_failed_precondition(tmp_path):
    ring = FrameRing((100, 160, 3), label="r2c2")
    plain = os.open(tmp_path / "secret", os.O_RDWR | os.O_CREAT)
    try:
        os.write(plain, b"\0" * (8 + 160 * 100 * 3))
        offset, seq = ring.write(np.zeros((100, 160, 3), np.uint8))
        with RoomServerThread(small_room()) as server:
            not_a_ring = _shared(ring, offset, seq, frame_id=1)
            not_a_ring.shared.fd = plain
            gone = _shared(ring, offset, seq, frame_id=1)
            gone.shared.pid = 2 ** 22 + 1       # above the kernel's pid_max: no such process
            for msg in (not_a_ring, gone):
                exc = _stream(server.address, [msg])
                assert isinstance(exc, grpc.RpcError) and exc.code() == grpc.StatusCode.FAILED_PRECONDITION, exc
            outside = _shared(ring, ring.stride * ring.count - 10, seq, frame_id=1)
            exc = _stream(server.address, [outside])
            assert exc.code() == grpc.StatusCode.INVALID_ARGUMENT and "outside" in exc.details()
            assert server.server.service.frames_received == 0
    finally:
        os.close(plain)
        ring.close()


def _can_unshare() -> bool:
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        return False
    return subprocess.run(["unshare", "--fork", "--pid", "--mount-proc", "true"], capture_output=True).returncode == 0


@pytest.mark.skipif(not _can_unshare(), reason="needs root and unshare(1) for a room in a PID namespace of its own")
def test_a_room_that_cannot_see_the_node_process_gets_its_frames_inline():
    room = subprocess.Popen(
        ["unshare", "--fork", "--pid", "--mount-proc", "--kill-child",
         sys.executable, "-m", "shadowless", "room", "--port", "0", "--no-noise",
         "--projector-scale", "0.125", "--camera-scale", "0.125"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    out = None
    try:
        line = room.stdout.readline()
        m = re.search(r"listening on (127\.0\.0\.1:\d+)", line)
        assert m, line + (room.stderr.read() if room.poll() is not None else "")
        with RoomClient(m.group(1)) as client:
            out = RoomOutput(f"room://{m.group(1)}", slot="r2c2")
            assert out.shares_frames
            w, h = out.native_size()
            out.after_swap(StandInRenderer(w, h).show(255), info(7))
            seen = wait_until(lambda: (client.capture().frames.get("r2c2", (0, 0))[0], out.shares_frames, out.last_error),
                              lambda s: s[0] == 7, what="frame 7 in the room, sent inline once it refused the memory")
            assert seen[1] is False and "FAILED_PRECONDITION" in seen[2]
            np.testing.assert_array_equal(out.last_image, np.full((h, w, 3), 255, np.uint8))
    finally:
        if out is not None:
            out.close()
        # the room is the namespace's pid 1, which ignores a SIGTERM it has no handler for (unshare passes
        # it on); SIGKILL ends unshare, and --kill-child the room with it
        room.kill()
        room.wait(timeout=30)
