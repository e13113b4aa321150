"""node/session.py: the protocol core the node and the swarm share, on scripted links.

The clock-id rule (an estimate survives a coordinator restart on the same rig clock, never a new
clock), the handshake's proofs both ways (and the random-proof Join that tells an untrusted
coordinator why it is not joined), the clock a heartbeat carries, and the assignment a rejoin sends
again, which the presenter is not given twice. A real coordinator restarted
under both the node's and the swarm's cores is tests/shadowless/test_swarm.py's.
"""
from __future__ import annotations

import asyncio
import logging

import numpy as np
import pytest

from node.clock import ClockSample, LocalClock
from node.errors import CoordinatorNotTrusted
from node import wire
from node.records import AssignmentBytes, HelloReply, JoinReply, NodeInfo, PingReply
from node.session import SessionCore
from protos import auth, node_pb2
from protos.blend import BlendMaps

TOKEN = b"t" * 32
RIG = "rig-1"
OFFSET_NS = 5_000_000_000       # the scripted coordinator's clock runs this far ahead of the host's


def core(**kw) -> SessionCore:
    return SessionCore(slot="r0c0", token=TOKEN, clock=LocalClock(), info=lambda: NodeInfo(hostname="h"), **kw)


def feed(c: SessionCore, n: int = 12) -> None:
    """Exchanges a second apart, on a rig clock OFFSET_NS ahead of the local one."""
    for i in range(n):
        t0 = i * 1_000_000_000
        c.estimator.add(ClockSample(t0, t0 + OFFSET_NS + 100_000, t0 + OFFSET_NS + 110_000, t0 + 200_000))


def reply(instance: str, clock_id: str) -> JoinReply:
    return JoinReply(session="s", instance_id=instance, heartbeat_interval_ms=500, clock_id=clock_id)


def test_the_clock_id_rule_keeps_the_estimate_on_the_same_rig_clock_only():
    c = core()
    assert c.adopt(reply("i1", "monotonic:boot")) is False    # a first join starts afresh
    feed(c)
    est = c.estimator.estimate
    assert est is not None and est.samples == 12
    c.settled = True
    assert c.adopt(reply("i1", "monotonic:boot")) is True     # the same instance again
    assert c.adopt(reply("i2", "monotonic:boot")) is True     # restarted on its host: same clock
    assert c.estimator.estimate == est and c.settled
    assert c.adopt(reply("i3", "instance:i3")) is False       # another clock: dropped, unsettled
    assert c.estimator.estimate is None and not c.settled
    feed(c)
    assert c.adopt(reply("i4", "")) is False                  # a coordinator that names no clock
    assert c.estimator.estimate is None
    feed(c)
    assert c.adopt(reply("i5", "")) is False                  # ... never counts as the same one
    assert c.estimator.estimate is None


class ScriptedCoordinator:
    """Answers hello, join and ping as a coordinator on a clock OFFSET_NS ahead of the host's
    would; ``honest=False`` cannot prove the token."""

    target = "scripted:1"

    def __init__(self, *, honest: bool = True, clock_id: str = "monotonic:boot", instance: str = "i1"):
        self.honest, self.clock_id, self.instance = honest, clock_id, instance
        self.joins = []

    async def hello(self, *, protocol_version, client_nonce, slot, timeout=5.0):
        self.server_nonce = auth.new_nonce()
        proof = auth.coordinator_proof(TOKEN if self.honest else b"w" * 32, RIG, client_nonce, self.server_nonce)
        return HelloReply(rig_id=RIG, rig_name="table", server_nonce=self.server_nonce, server_proof=proof)

    async def join(self, request):
        self.joins.append(request)
        return reply(self.instance, self.clock_id)

    async def ping(self, t0_local_ns):
        rig = LocalClock().now() + OFFSET_NS
        return PingReply(t1_rig_ns=rig, t2_rig_ns=rig)


def test_a_join_proves_the_token_and_carries_the_info():
    c, link = core(), ScriptedCoordinator()
    joined = asyncio.run(c.join(link))
    assert joined.hello.rig_id == RIG and joined.reply.instance_id == "i1"
    assert joined.previous_instance == "" and joined.clock_kept is False
    (req,) = link.joins
    assert req.slot == "r0c0" and req.info == NodeInfo(hostname="h")
    assert req.client_proof == auth.client_proof(TOKEN, "node", RIG, "r0c0", req.client_nonce, req.server_nonce)

    link.instance = "i2"                                       # the coordinator restarted on its host
    again = asyncio.run(c.join(link))
    assert again.previous_instance == "i1" and again.clock_kept is True


def test_an_untrusted_coordinator_is_told_with_a_random_proof_and_not_joined():
    c, link = core(), ScriptedCoordinator(honest=False)
    with pytest.raises(CoordinatorNotTrusted, match="could not prove it knows the rig token"):
        asyncio.run(c.join(link))
    (told,) = link.joins                                       # one Join, to show up in its status ...
    real = auth.client_proof(TOKEN, "node", RIG, "r0c0", told.client_nonce, told.server_nonce)
    assert len(told.client_proof) == len(real) and told.client_proof != real   # ... never with the real proof
    assert c.instance_id == ""                                 # and nothing of it adopted


def test_pings_build_the_estimate_a_heartbeat_carries():
    c, link = core(), ScriptedCoordinator()

    async def go():
        await c.join(link)
        await c.ping_burst(link)

    asyncio.run(go())
    host, status = c.clock_status()
    assert status is not None and status.samples >= 1
    assert abs(status.offset_ns - OFFSET_NS) < 50_000_000       # the scripted clock's lead, within the round trip
    assert abs(c.rig_time(host) - status.rig_estimate_ns) <= 1
    assert abs(c.host_time(status.rig_estimate_ns) - host) <= 1


def assignment(revision: int, *, gain: float = 1.0, blend: BlendMaps | None = None, blend_at_ns: int = 0
               ) -> AssignmentBytes:
    """An assignment as the node process holds it (its bytes), from the message a coordinator sends."""
    msg = node_pb2.Assignment(revision=revision, slot="r0c0", output_width=64, output_height=48, gain=gain,
                              content_width=64, content_height=48)
    msg.homography.m.extend(np.eye(3).ravel().tolist())
    if blend is not None:
        alpha, beta = blend.encode()
        (w, h) = blend.size
        msg.blend.CopyFrom(node_pb2.Blend(width=w, height=h, alpha=alpha, beta=beta, blend_id=blend.blend_id,
                                          at_rig_ns=blend_at_ns))
    return wire.assignment_bytes(msg)


def maps(level: float) -> BlendMaps:
    return BlendMaps(np.full((4, 6, 3), level, np.float32), np.zeros((4, 6), np.float32))


def test_an_assignment_equal_but_for_its_revision_is_not_passed_again_and_reported_under_its_new_number():
    c = core()
    c.adopt(reply("i1", "monotonic:boot"))
    assert c.assignment_revision(0) == 0                          # the presenter holds nothing yet
    assert c.assignment_news(assignment(3, blend=maps(0.5), blend_at_ns=7))
    assert c.assignment_revision(3) == 3
    c.adopt(reply("i2", "monotonic:boot"))                        # restarted on its host
    assert c.assignment_revision(3) == 0                          # r3 was the old instance's number
    assert not c.assignment_news(assignment(1, blend=maps(0.5), blend_at_ns=7))   # the same, renumbered
    assert c.assignment_revision(3) == 1                          # what the presenter holds is r1 now
    for changed in (assignment(2, gain=0.9, blend=maps(0.5), blend_at_ns=7),
                    assignment(3, blend=maps(0.25), blend_at_ns=7),
                    assignment(4, blend=maps(0.25), blend_at_ns=9),
                    assignment(5)):
        assert c.assignment_news(changed), changed.revision       # any other change goes to the presenter
    assert c.assignment_revision(5) == 5 and c.assignment_revision(4) == 4
    c.adopt(reply("i3", "instance:i3"))                           # another rig clock: everything is passed
    assert c.assignment_news(assignment(1))


def test_an_assignment_the_presenter_could_not_take_is_refused_whole_and_the_one_held_kept(caplog):
    c = core()
    c.adopt(reply("i1", "monotonic:boot"))
    assert c.assignment_news(assignment(3))
    bad = node_pb2.Assignment.FromString(assignment(4, gain=0.5).data)
    del bad.homography.m[-1]
    bad.revision = 4
    with caplog.at_level(logging.INFO, logger="node"):
        assert not c.assignment_news(wire.assignment_bytes(bad))
    lines = [r.getMessage() for r in caplog.records if "r4" in r.getMessage()]
    assert lines == ["r0c0: assignment r4 refused (homography needs 9 values, got 8); the projector keeps r3"]
    assert c.refused == "r4: homography needs 9 values, got 8"
    assert c.assignment_revision(3) == 3 and c.assignment_revision(4) == 0   # heartbeats name the one kept
    assert not c.assignment_news(assignment(5))       # the one held, renumbered: still recognised as held
    assert c.assignment_revision(3) == 5 and c.refused == ""
