"""The handshake keeps no state for Hello (a flood cannot push out a joining node's nonce),
nonces are single use and expire; refusals are counted per address, slot and reason."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.wire import image_parts
from coordinator.api import Space
from coordinator.errors import Refusal, RefusalKind
from coordinator.refusals import MAX_KEYS, RELOG_S, Refusals, peer_address
from coordinator.sessions import NONCE_TTL_S, Handshake
from protos import auth, codec
from protos.version import PROTOCOL_VERSION

TOKEN = auth.new_token().encode()


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def make(clock=None, token=TOKEN):
    refusals = Refusals()
    clock = clock or Clock()
    hs = Handshake(token, rig_id="rig-1", rig_name="table", instance_id="i", clock=clock,
                   on_refusal=lambda peer, slot, msg: refusals.record(peer, slot, msg, clock()))
    return hs, refusals, clock


def hello(hs, peer="ipv4:10.0.0.9:4000"):
    cn = auth.new_nonce()
    r = hs.hello(protocol_version=PROTOCOL_VERSION, client_nonce=cn, role="node", slot="p1", peer=peer)
    assert auth.verify(auth.coordinator_proof(TOKEN, "rig-1", cn, r.server_nonce), r.server_proof)
    return cn, r.server_nonce


def login(hs, cn, sn, *, token=TOKEN, peer="ipv4:10.0.0.9:4000"):
    proof = auth.client_proof(token, "node", "rig-1", "p1", cn, sn)
    hs.check_login(protocol_version=PROTOCOL_VERSION, role="node", slot="p1", client_nonce=cn, server_nonce=sn,
                   client_proof=proof, peer=peer, expected_role="node")


def test_a_hello_flood_leaves_no_state_and_a_join_in_between_succeeds():
    hs, _, _ = make()
    cn, sn = hello(hs)
    for _ in range(20000):                      # a flood after the node's Hello, before its Join
        hello(hs, peer="ipv4:10.0.0.66:5000")
    assert hs.used == {}
    login(hs, cn, sn)
    assert len(hs.used) == 1


def test_nonces_are_single_use():
    hs, refusals, _ = make()
    cn, sn = hello(hs)
    login(hs, cn, sn)
    with pytest.raises(Refusal) as err:
        login(hs, cn, sn)
    assert err.value.kind == RefusalKind.UNAUTHENTICATED and "single use" in err.value.message


def test_nonces_expire():
    hs, _, clock = make()
    cn, sn = hello(hs)
    clock.t += NONCE_TTL_S + 1
    with pytest.raises(Refusal, match="expired"):
        login(hs, cn, sn)


@pytest.mark.parametrize("tamper", ["other client nonce", "flipped bit", "other instance", "short"])
def test_a_nonce_not_issued_for_this_client_by_this_instance_is_refused(tamper):
    hs, _, clock = make()
    cn, sn = hello(hs)
    if tamper == "other client nonce":
        cn = auth.new_nonce()
    elif tamper == "flipped bit":
        sn = sn[:5] + bytes([sn[5] ^ 1]) + sn[6:]   # e.g. a later expiry
    elif tamper == "other instance":
        other, _, _ = make(clock)
        cn, sn = hello(other)
    else:
        sn = sn[:16]
    with pytest.raises(Refusal, match="expired or unknown"):
        login(hs, cn, sn)


def test_a_wrong_token_is_refused_and_counted_per_address():
    hs, refusals, clock = make()
    bad = auth.new_token().encode()
    for port in range(3):
        cn, sn = hello(hs)
        with pytest.raises(Refusal, match="rig token mismatch"):
            login(hs, cn, sn, token=bad, peer=f"ipv4:10.0.0.7:{5000 + port}")
    (r,) = refusals.summary(clock())
    assert (r.peer, r.slot, r.count) == ("10.0.0.7", "p1", 3) and "rig token mismatch" in r.reason


def test_peer_address_strips_the_port():
    assert peer_address("ipv4:10.0.0.5:51234") == "10.0.0.5"
    assert peer_address("ipv6:[::1]:5000") == "::1"
    assert peer_address("unix:/tmp/x") == "unix:/tmp/x"


def test_refusals_log_once_then_once_a_minute_with_the_count():
    r = Refusals()
    lines = [r.record(f"ipv4:10.0.0.1:{i}", "p1", "rig token mismatch", float(i)) for i in range(200)]
    logged = [(i, line) for i, line in enumerate(lines) if line]
    assert [i for i, _ in logged] == [0, 60, 120, 180]
    assert "60 more times in 60 s, 61 in all" in logged[1][1]
    assert RELOG_S == 60.0


def test_refusals_are_bounded_and_newest_first():
    r = Refusals()
    for i in range(MAX_KEYS + 50):
        r.record(f"ipv4:10.1.{i // 256}.{i % 256}:1", "", "bad", float(i))
    s = r.summary(float(MAX_KEYS + 50), limit=10_000)
    assert len(s) == MAX_KEYS
    assert s[0].peer == f"10.1.{(MAX_KEYS + 49) // 256}.{(MAX_KEYS + 49) % 256}"
    assert r.total() == MAX_KEYS


def test_image_parts_reassemble_exactly_and_refuse_overflow():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 65535, (700, 900, 3), dtype=np.uint16)   # incompressible: several parts
    parts = image_parts.show_request_parts(img, name="x", persist=False, space=Space.CONTENT, apply_lut=True, fit="cover")
    assert len(parts) > 2 and all(p.ByteSize() <= image_parts.IMAGE_PART_BYTES + 1024 for p in parts)
    asm = image_parts.ImageParts()
    asm.start(parts[0].image)
    for p in parts[1:]:
        asm.add(p.more)
    np.testing.assert_array_equal(codec.decode_image(asm.finish()), img)
    assert parts[0].fit == "cover"

    small = image_parts.show_request_parts(np.zeros((4, 4, 1), np.uint8), name="", persist=False, space=Space.CONTENT,
                                    apply_lut=True)
    asm.start(small[0].image)
    with pytest.raises(ValueError, match="sent more than"):
        asm.add(b"\0" * (ImagePartsMargin() + 100))


def ImagePartsMargin() -> int:
    return image_parts.ImageParts.MARGIN


def test_image_parts_check_the_header_before_any_data():
    msg = codec.encode_image(np.zeros((4, 4, 1), np.uint8))
    msg.width = 100_000
    with pytest.raises(codec.ImageCodecError, match="outside"):
        image_parts.ImageParts().start(msg)
    with pytest.raises(ValueError, match="before the image"):
        image_parts.ImageParts().add(b"x")
