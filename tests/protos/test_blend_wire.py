"""Blend maps as both sides speak them: the record (protos/blend.py) and its checks, a slot's maps in
the coordinator's Assignment and back out on a node, what a node reports of the blend on its screen
in its heartbeat and where the coordinator keeps it (its node session). Messages go through bytes,
as on the wire; older peers (no blend fields) read as no blend."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from coordinator.rig import HomographyPose, SlotState
from coordinator.sessions import NodeInfo, NodeSession
from coordinator.wire import node_messages
from node import wire
from node.records import HeartbeatRecord, ReportBatch
from protos import node_pb2
from protos.blend import MAX_MAP_SIDE, BlendMapError, BlendMaps


def halves(shape, seed=0) -> np.ndarray:
    """Values float16 holds exactly (so a round trip through the wire is exact)."""
    return (np.random.default_rng(seed).integers(0, 1025, shape) / 1024).astype(np.float32)


def maps(w=8, h=6, seed=0) -> BlendMaps:
    return BlendMaps(halves((h, w, 3), seed), halves((h, w), seed + 1))


# ----------------------------------------------------------------------------- the record


@pytest.mark.parametrize("alpha, beta, words", [
    (np.ones((4, 5)), np.zeros((4, 5)), "alpha map must be (h, w, 3)"),
    (np.ones((4, 5, 4)), np.zeros((4, 5)), "alpha map must be (h, w, 3)"),
    (np.ones((4, 5, 3)), np.zeros((5, 4)), "beta map must be (h, w) = (4, 5)"),
    (np.full((4, 5, 3), np.nan), np.zeros((4, 5)), "alpha map holds NaN"),
    (np.ones((4, 5, 3)), np.full((4, 5), np.inf), "beta map holds NaN or infinite"),
    (np.full((4, 5, 3), 1.5), np.zeros((4, 5)), "alpha map must lie in 0..1"),
    (np.ones((4, 5, 3)), np.full((4, 5), -0.1), "beta map must lie in 0..1"),
    (np.ones((0, 5, 3)), np.zeros((0, 5)), "1..4096 texels per side"),
    (np.ones((1, MAX_MAP_SIDE + 1, 3)), np.zeros((1, MAX_MAP_SIDE + 1)), "1..4096 texels per side"),
])
def test_bad_maps_are_refused_in_one_line(alpha, beta, words):
    with pytest.raises(BlendMapError) as err:
        BlendMaps(alpha, beta)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_the_record_encodes_as_float16_and_decodes_exactly():
    m = maps(9, 7)
    assert m.size == (9, 7) and m.alpha.dtype == np.float32 and not m.alpha.flags.writeable
    a, b = m.encode()
    assert len(a) == 9 * 7 * 3 * 2 and len(b) == 9 * 7 * 2
    back = BlendMaps.decode(9, 7, a, b, m.blend_id)
    assert (back.alpha == m.alpha).all() and (back.beta == m.beta).all() and back.blend_id == m.blend_id
    assert BlendMaps.decode(9, 7, a, b).blend_id == m.blend_id, "the id is a digest of the maps as sent"
    assert maps(9, 7, seed=5).blend_id != m.blend_id
    with pytest.raises(BlendMapError, match="need 378 \\+ 126 bytes"):
        BlendMaps.decode(9, 7, a[:-2], b)


def test_decoding_checks_the_halves_bits_as_the_arrays_check_their_values():
    """Every float16 bit pattern: decoded maps hold exactly the float32 values of the halves sent when
    all lie in 0..1 (subnormals, -0 and 1.0 included), and anything else is refused with the arrays' own
    one line (NaN, infinite, above 1, negative); the reference is numpy's float16 to float32."""
    every = np.arange(2 ** 16, dtype=np.uint16)
    values = every.view("<f2").astype(np.float32)
    good = np.isfinite(values) & (values >= 0) & (values <= 1)
    assert good.sum() == 0x3C01 + 1
    ok = every[good]
    rng = np.random.default_rng(3)
    w, h = 64, ok.size // 64 // 3
    a = rng.permutation(ok)[: w * h * 3].astype("<u2").tobytes()
    b = rng.permutation(ok)[: w * h].astype("<u2").tobytes()
    got = BlendMaps.decode(w, h, a, b)
    want = BlendMaps(np.frombuffer(a, "<f2").reshape(h, w, 3).astype(np.float32),
                     np.frombuffer(b, "<f2").reshape(h, w).astype(np.float32))
    assert np.array_equal(got.alpha, want.alpha) and np.array_equal(got.beta, want.beta)
    assert got.blend_id == want.blend_id and got.encode() == (a, b)
    for bits in rng.choice(every[~good], 40, replace=False):
        v = float(np.uint16(bits).view("<f2"))
        bad = np.frombuffer(a, "<u2").copy()
        bad[17] = bits
        with pytest.raises(BlendMapError) as err:
            BlendMaps.decode(w, h, bad.tobytes(), b)
        words = "holds NaN or infinite" if not np.isfinite(v) else "must lie in 0..1"
        assert str(err.value).startswith("alpha map") and words in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(BlendMapError, match="texels per side"):
        BlendMaps.decode(0, 7, b"", b"")


# ----------------------------------------------------------------------------- coordinator -> node


def slot(**changes) -> SlotState:
    st = SlotState(name="r0c1", width=64, height=48, revision=3, gain=0.8, pose=HomographyPose(np.eye(3)))
    return replace(st, **changes)


def through_the_wire(st: SlotState):
    msg = node_messages.assignment_message(st, content_size=(64, 48))
    return wire.assignment_from_message(node_pb2.Assignment.FromString(msg.SerializeToString()))


def test_a_slots_maps_reach_the_node_with_their_instant():
    m = maps(16, 12)
    a = through_the_wire(slot(blend=m, blend_at_ns=123_456_789_000))
    assert a.blend is not None and a.blend_error == ""
    assert (a.blend.alpha == m.alpha).all() and (a.blend.beta == m.beta).all()
    assert a.blend.blend_id == m.blend_id and a.blend_at_ns == 123_456_789_000
    assert a.gain == pytest.approx(0.8) and a.pose_kind == "homography"


def test_no_maps_is_no_blend_and_an_older_coordinator_sends_none():
    a = through_the_wire(slot())
    assert a.blend is None and a.blend_at_ns == 0 and a.blend_error == ""
    old = node_pb2.Assignment(revision=1, slot="r0c1", output_width=64, output_height=48)
    assert wire.assignment_from_message(old).blend is None


@pytest.mark.parametrize("spoil, words", [
    (lambda b: setattr(b, "alpha", b.alpha[:-2]), "bytes"),
    (lambda b: setattr(b, "width", 0), "texels per side"),
    (lambda b: setattr(b, "beta", np.full(b.width * b.height, np.nan, "<f2").tobytes()), "NaN"),
    (lambda b: setattr(b, "alpha", np.full(b.width * b.height * 3, 2.0, "<f2").tobytes()), "0..1"),
])
def test_malformed_maps_reach_the_node_as_an_error_and_the_rest_of_the_assignment_stands(spoil, words):
    msg = node_messages.assignment_message(slot(blend=maps()), content_size=(64, 48))
    spoil(msg.blend)
    a = wire.assignment_from_message(node_pb2.Assignment.FromString(msg.SerializeToString()))
    assert a.blend is None and words in a.blend_error and "\n" not in a.blend_error
    assert a.revision == 3 and a.gain == pytest.approx(0.8) and a.homography is not None


# ----------------------------------------------------------------------------- node -> coordinator


def session() -> NodeSession:
    return NodeSession(session="s", slot="r0c1", peer="test", info=NodeInfo(), instance_joins=1, joined=0.0,
                       last_seen=0.0)


def test_the_heartbeat_says_which_maps_are_on_screen_and_since_when():
    hb = HeartbeatRecord(assignment_revision=4, frames_shown=1, frames_late=0, frames_dropped=0, render_ms_p50=1.0,
                         host_monotonic_ns=5, blend_id="abc123", blend_since_rig_ns=987_654_321)
    data = wire.report_message(ReportBatch(heartbeat=hb)).SerializeToString()
    rep = node_messages.report_from_message(node_pb2.NodeReport.FromString(data))
    assert (rep.heartbeat.blend_id, rep.heartbeat.blend_since_rig_ns) == ("abc123", 987_654_321)
    s = session()
    assert (s.blend_id, s.blend_since_rig_ns) == ("", 0), "no heartbeat yet: no blend known"
    s.heartbeat = rep.heartbeat                    # what the core does with each heartbeat
    assert (s.blend_id, s.blend_since_rig_ns) == ("abc123", 987_654_321)
    # an older node's heartbeat has no blend: none
    old = node_pb2.NodeReport(heartbeat=node_pb2.Heartbeat(assignment_revision=4))
    s.heartbeat = node_messages.report_from_message(old).heartbeat
    assert (s.blend_id, s.blend_since_rig_ns) == ("", 0)
