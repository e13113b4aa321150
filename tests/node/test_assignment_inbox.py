"""node/presenter_process.py's Inbox: the presenter process's end of the pipe from the node process,
which passes an assignment on as its bytes (the node process imports no numpy); the presenter gets
it decoded, every other message as it was sent, and a malformed assignment is skipped. Real pipes.
"""
from __future__ import annotations

from multiprocessing import Pipe

import numpy as np
import pytest

from node import wire
from node.presenter_process import Inbox
from node.records import AssignmentBytes, FrameOrder, NodeAssignment
from protos import node_pb2


def message(revision: int, homography: list[float]) -> AssignmentBytes:
    msg = node_pb2.Assignment(revision=revision, slot="r0c0", output_width=64, output_height=48,
                              content_width=64, content_height=48)
    msg.homography.m.extend(homography)
    return wire.assignment_bytes(msg)


def pipe():
    reader, writer = Pipe(duplex=False)
    return Inbox(reader), writer


def test_assignments_arrive_decoded_and_everything_else_as_sent_in_order():
    inbox, writer = pipe()
    frame = FrameOrder(frame_id=1, pts_ns=2, content_id="c", space="content", apply_lut=False, tag="")
    rec = message(5, list(np.eye(3).ravel()))
    writer.send(("frame", frame))
    writer.send(("assignment", rec))
    writer.send(("show", None))
    assert inbox.recv() == ("frame", frame)
    assert inbox.poll(5.0)
    kind, a = inbox.recv()
    assert kind == "assignment" and isinstance(a, NodeAssignment)
    assert a.revision == 5 and a.received_host_ns == rec.received_host_ns <= a.decoded_host_ns
    np.testing.assert_array_equal(a.homography, np.eye(3))
    assert inbox.recv() == ("show", None)
    assert not inbox.poll(0.0)
    writer.send(("stats", 1))
    assert inbox.poll(None) and inbox.recv() == ("stats", 1)      # None: waits until a message is there


def test_a_malformed_assignment_is_skipped_and_logged(caplog):
    inbox, writer = pipe()
    writer.send(("assignment", message(6, [1.0] * 10)))      # a homography of 10 values
    assert not inbox.poll(0.2)                               # nothing for the presenter
    assert "ignoring a malformed assignment r6: homography needs 9 values" in caplog.text
    writer.send(("assignment", message(7, list(np.eye(3).ravel()))))
    assert inbox.poll(5.0) and inbox.recv()[1].revision == 7


def test_an_assignment_already_decoded_passes_as_it_is():
    inbox, writer = pipe()
    a = wire.assignment_from_bytes(message(8, list(np.eye(3).ravel())))
    writer.send(("assignment", a))
    assert inbox.recv()[1].revision == 8


def test_the_end_of_the_pipe_is_seen_by_poll_and_raised_by_recv():
    inbox, writer = pipe()
    writer.send(("stats", None))
    writer.close()
    assert inbox.poll(5.0) and inbox.recv() == ("stats", None)
    assert inbox.poll(5.0)                    # the node process is gone: recv says so at once
    with pytest.raises(EOFError):
        inbox.recv()
