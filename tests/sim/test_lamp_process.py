"""A lamp that dims or dies while its projector keeps showing frames, switched through a real
`shadowless room` process (RoomTruth.SetLamp, what a benchmark calls): the captures change where
that projector alone lights the wall, and the truth says so."""
from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim.errors import FrameError, UnknownSlotError
from sim.link import RoomClient

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def wall_room():
    proc = subprocess.Popen(
        [sys.executable, "-m", "shadowless", "room", "--layout", "wall-3x1", "--port", "0", "--no-noise",
         "--projector-scale", "0.125", "--camera-scale", "0.125", "--white-spread", "0.1", "--hotspot", "0.2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    try:
        line = proc.stdout.readline()
        m = re.search(r"listening on (127\.0\.0\.1:\d+)", line)
        assert m, line + (proc.stderr.read() if proc.poll() is not None else "")
        with RoomClient(m.group(1)) as client:
            yield client
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_lamp_switched_over_the_wire_changes_captures_and_truth(wall_room):
    client = wall_room
    d = client.describe()
    assert list(d.rig_slots) == ["r0c0", "r0c1", "r0c2"] and d.name == "wall-3x1-overlap-20"
    w, h = client.projector_size("r0c1")
    client.display({s: np.full((h, w, 3), 200, np.uint8) for s in d.rig_slots}, frame_id=1)
    before = client.capture().image
    alone = {s: client.contribution(s)[..., 1] for s in d.rig_slots}
    only_mid = (alone["r0c1"] > 0.05) & (alone["r0c0"] == 0) & (alone["r0c2"] == 0)
    only_left = (alone["r0c0"] > 0.05) & (alone["r0c1"] == 0)
    assert only_mid.sum() > 1000 and only_left.sum() > 1000
    truth = client.projector_truth("r0c1")
    assert list(truth.lamp) == [1.0, 1.0, 1.0] and truth.hotspot == pytest.approx(0.2)
    assert all(0.9 <= g <= 1.1 for g in truth.white) and len(set(truth.white)) == 3

    assert client.set_lamp("r0c1", 0.5).tolist() == [0.5, 0.5, 0.5]
    dimmed = client.capture().image
    np.testing.assert_allclose(dimmed[only_mid], 0.5 * before[only_mid], atol=2.0 / 4095)
    np.testing.assert_array_equal(dimmed[only_left], before[only_left])     # the others are untouched
    assert list(client.projector_truth("r0c1").lamp) == [0.5, 0.5, 0.5]
    np.testing.assert_allclose(client.contribution("r0c1")[..., 1], 0.5 * alone["r0c1"], rtol=1e-5, atol=1e-7)

    client.set_lamp("r0c1", 0.0)                                            # dead, its node still streaming
    dead = client.capture()
    assert dead.image[only_mid].max() == 0.0 and dead.frames["r0c1"][0] == 1
    assert not client.contribution("r0c1").any()

    with pytest.raises(FrameError, match="lamp gain must be in 0..1"):
        client.set_lamp("r0c1", 1.5)
    with pytest.raises(FrameError, match="one number or three"):
        client.set_lamp("r0c1", [0.5, 0.5])
    with pytest.raises(UnknownSlotError, match="no projector 'zz'"):
        client.set_lamp("zz", 0.5)
    assert list(client.projector_truth("r0c1").lamp) == [0.0, 0.0, 0.0]    # the refusals changed nothing
    client.set_lamp("r0c1", 1)
    np.testing.assert_array_equal(client.capture().image, before)


STREAMER = """
import sys, threading
import numpy as np
from sim.link import RoomClient
address, slot, w, h = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
hold = threading.Event()

def frames():
    from protos import codec, room_pb2
    yield room_pb2.DisplayedFrame(slot=slot, frame_id=7, image=codec.encode_image(np.full((h, w, 3), 255, np.uint8)))
    print("sent", flush=True)
    hold.wait()                      # a node that streams on until it is killed

with RoomClient(address) as client:
    client._call(client._room.Display, frames(), timeout=600)
"""


def test_a_killed_node_leaves_its_projector_black_when_asked():
    """`--no-signal black`: a projector no stream feeds any more (its node was killed) shows black,
    its black level staying, while the others keep theirs (without the flag every projector keeps
    its last frame, as the room always did)."""
    from waits import wait_until

    room = subprocess.Popen(
        [sys.executable, "-m", "shadowless", "room", "--layout", "wall-3x1", "--port", "0", "--no-noise",
         "--projector-scale", "0.125", "--camera-scale", "0.125", "--no-signal", "black"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    nodes = {}
    try:
        m = re.search(r"listening on (127\.0\.0\.1:\d+)", room.stdout.readline())
        assert m
        with RoomClient(m.group(1)) as client:
            w, h = client.projector_size("r0c1")
            alone = {s: client.contribution(s)[..., 1] for s in ("r0c0", "r0c1")}
            mid, left = (alone["r0c1"] > 0.2) & (alone["r0c0"] == 0), (alone["r0c0"] > 0.2) & (alone["r0c1"] == 0)
            assert mid.sum() > 1000 and left.sum() > 1000
            for slot in ("r0c0", "r0c1"):
                nodes[slot] = subprocess.Popen([sys.executable, "-c", STREAMER, m.group(1), slot, str(w), str(h)],
                                               stdout=subprocess.PIPE, text=True, cwd=ROOT)
                assert nodes[slot].stdout.readline().strip() == "sent"
            wait_until(lambda: client.capture().image, lambda img: img[mid].min() > 0.2 and img[left].min() > 0.2,
                       what="r0c0's and r0c1's white on the wall")
            nodes["r0c1"].kill()
            nodes["r0c1"].wait()
            dark = wait_until(lambda: client.capture().image, lambda img: img[mid].max() < 0.05,
                              what="r0c1 black once its node is killed")
            assert dark[mid].min() > 0                            # black, not off: its black level stays
            assert dark[left].min() > 0.2                         # the live node's frame stays
        room.send_signal(signal.SIGTERM)
        assert room.wait(timeout=30) == 0
    finally:
        for p in (*nodes.values(), room):
            if p.poll() is None:
                p.kill()
                p.wait()
