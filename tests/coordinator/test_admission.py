"""The budget for calls before authentication: a burst of large unauthenticated messages under the
size cap is refused unread beyond the budget, counted in status, logged once per address and
reason without a traceback, and costs no node its place."""
from __future__ import annotations

import asyncio
import collections

import grpc
import pytest

from coordinator.admission import MIB, Budget, budget_key, trim_memory
from coordinator.api import NodeState
from protos import auth, common_pb2, node_pb2
from protos.version import PROTOCOL_VERSION
from shadowless.local import LocalRig
from waits import wait_until_async


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_budget_caps_calls_and_reserved_bytes_per_address_and_in_all():
    b = Budget(reserve_bytes=4 * MIB, max_calls=5, max_calls_per_address=3, max_bytes=13 * MIB,
               max_bytes_per_address=9 * MIB, clock=FakeClock())
    a1, a2 = b.admit("ipv4:10.0.0.1:5000"), b.admit("ipv4:10.0.0.1:5001")
    assert a1 and a2 and a1.address == "10.0.0.1"
    assert b.admit("ipv4:10.0.0.1:5002") is None, "a third 4 MiB reservation passes the address's 9 MiB"
    b.received(a1, 100)                      # its message was small: the reservation shrinks to it
    a3 = b.admit("ipv4:10.0.0.1:5003")
    assert a3 is not None
    assert b.admit("ipv4:10.0.0.1:5004") is None, "three calls in flight from one address"
    b2 = b.admit("ipv6:[::1]:7000")
    assert b2 is not None and b2.address == "::1"
    assert b.admit("ipv6:[::1]:7001") is None, "13 MiB in all"
    f = b.figures()
    assert (f.in_flight_calls, f.in_flight_bytes, f.refused, f.admitted) == (4, 100 + 12 * MIB, 3, 4)
    for t in (a1, a2, a3, b2):
        b.release(t)
    b.release(a1)                            # twice: no effect
    f = b.figures()
    assert (f.in_flight_calls, f.in_flight_bytes) == (0, 0) and not b.by_address
    assert f.peak_bytes == 100 + 12 * MIB


def test_a_trim_follows_a_burst_once_it_has_been_idle():
    clock = FakeClock()
    b = Budget(reserve_bytes=4 * MIB, clock=clock)
    t = b.admit("ipv4:10.0.0.1:1")
    b.received(t, 3 * MIB)
    b.release(t)
    assert not b.should_trim(), "3 MiB is no burst"
    for _ in range(8):
        t = b.admit("ipv4:10.0.0.1:1")
        b.received(t, 3 * MIB)
        b.release(t)
    assert not b.should_trim(), "not yet idle for a second"
    clock.t += 1.5
    assert b.should_trim() and not b.should_trim(), "once per burst"
    assert trim_memory() >= 0


BURST = 60
SIZE = 3 * 1024 * 1024


async def _burst(port: int, method: str, calls: int, size: int, channels: int = 4) -> collections.Counter:
    """``calls`` concurrent calls of ``size`` bytes that are not a protobuf message; their status codes."""
    chans = [grpc.aio.insecure_channel(f"127.0.0.1:{port}", options=[("grpc.max_send_message_length", size + 1024)])
             for _ in range(channels)]
    codes: collections.Counter = collections.Counter()

    async def one(i):
        try:
            await chans[i % channels].unary_unary(method)(b"\xff" * size, timeout=120)
            codes["OK"] += 1
        except grpc.aio.AioRpcError as exc:
            codes[exc.code().name] += 1

    await asyncio.gather(*(one(i) for i in range(calls)))
    for c in chans:
        await c.close()
    return codes


@pytest.mark.slow
def test_a_burst_before_authentication_is_refused_counted_and_logged_once(tmp_path):
    rig = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False).create()
    try:
        rig.start_coordinator()
        rig.wait_ready()
        rig.start_node("r0c0")

        async def go():
            async with await rig.client() as c:
                await rig.wait_live(c, ["r0c0"])
                log_before = len(rig.log("coordinator"))
                codes = await _burst(rig.port, "/shadowless.v1.NodeLink/Hello", BURST, SIZE)
                # gRPC sends an aborted call's status before the call's handler unwinds and gives its room
                # back, so the last calls may still hold theirs for a moment after their callers heard
                st = await wait_until_async(c.status, lambda st: st.admission.in_flight_calls == 0,
                                            what="every call of the burst to give its room back")
                return codes, log_before, st

        codes, log_before, st = asyncio.run(go())
        assert set(codes) <= {"RESOURCE_EXHAUSTED", "INVALID_ARGUMENT"}, codes
        assert codes["RESOURCE_EXHAUSTED"] > 0, f"60 concurrent 3 MiB calls all fit the budget: {codes}"
        a = st.admission
        assert a.refused == codes["RESOURCE_EXHAUSTED"] and a.malformed == codes["INVALID_ARGUMENT"], (a, codes)
        assert a.peak_bytes <= a.max_bytes and a.in_flight_calls == 0
        reasons = {r.reason: r for r in st.refusals}
        over = next(r for k, r in reasons.items() if "over the budget" in k)
        malformed = next(r for k, r in reasons.items() if "malformed" in k)
        assert over.peer == "127.0.0.1" and over.count == a.refused and malformed.count == a.malformed
        node = next(n for n in st.nodes if n.slot == "r0c0")
        assert node.state == NodeState.LIVE and node.joins == 1, "the node kept its session through the burst"

        # the log names each (address, reason) once: the next line for it comes a minute later, with its count
        burst_log = rig.log("coordinator")[log_before:]
        lines = [ln for ln in burst_log.splitlines() if "refused" in ln]
        assert len(lines) == 2, "\n".join(lines[:10])
        assert "Traceback" not in burst_log and "ERROR" not in burst_log, burst_log[-3000:]

        table = rig.run_cli(["status"])
        assert f"before authentication: {a.refused} calls refused over the budget, {a.malformed} malformed" in table
    finally:
        rig.close()


def _raw_cases():
    """(what, method, request bytes, code, words): calls before authentication a peer can get wrong."""
    garbage = b"\xff" * 1000
    long_slot = common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, client_nonce=auth.new_nonce(), role="node",
                                        slot="x" * 50_000).SerializeToString()
    long_role = common_pb2.HelloRequest(protocol_version=99, client_nonce=auth.new_nonce(), role="r" * 10_000,
                                        slot="y" * 10_000).SerializeToString()
    path_slot = node_pb2.JoinRequest(login=common_pb2.LoginRequest(
        protocol_version=PROTOCOL_VERSION, role="node", slot="../../etc", client_nonce=auth.new_nonce(),
        server_nonce=auth.new_nonce(), client_proof=b"p" * 32)).SerializeToString()
    S = grpc.StatusCode
    return [
        ("NodeLink Hello of bytes that are no HelloRequest", "/shadowless.v1.NodeLink/Hello", garbage,
         S.INVALID_ARGUMENT, ["malformed /shadowless.v1.NodeLink/Hello request (not the method's message"]),
        ("NodeLink Hello of 100 KiB", "/shadowless.v1.NodeLink/Hello", b"\0" * 100 * 1024, S.INVALID_ARGUMENT,
         ["larger than the 64 KiB a call without a session may send"]),
        ("NodeLink Join of bytes that are no JoinRequest", "/shadowless.v1.NodeLink/Join", garbage,
         S.INVALID_ARGUMENT, ["malformed /shadowless.v1.NodeLink/Join request"]),
        ("RigControl Login of bytes that are no LoginRequest", "/shadowless.v1.RigControl/Login", garbage,
         S.INVALID_ARGUMENT, ["malformed /shadowless.v1.RigControl/Login request"]),
        ("Health Check of bytes that are no request", "/grpc.health.v1.Health/Check", garbage,
         S.INVALID_ARGUMENT, ["malformed /grpc.health.v1.Health/Check request"]),
        ("Hello for a 50,000-character slot", "/shadowless.v1.NodeLink/Hello", long_slot, S.INVALID_ARGUMENT,
         ["is not a slot name", "…"]),
        ("Hello of protocol 99 with a 10,000-character role and slot", "/shadowless.v1.RigControl/Hello", long_role,
         S.FAILED_PRECONDITION, ["protocol version mismatch", "99"]),
        ("Server reflection stream of bytes that are no request",
         "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo", garbage, S.INVALID_ARGUMENT,
         ["malformed /grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo request"]),
        ("Join for the slot '../../etc'", "/shadowless.v1.NodeLink/Join", path_slot, S.INVALID_ARGUMENT,
         ["'../../etc' is not a slot name"]),
    ]


def test_calls_before_authentication_get_one_clear_line(tmp_path, corpus_table):
    rig = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False).create()
    try:
        rig.start_coordinator()
        rig.wait_ready()

        async def go():
            out = []
            async with grpc.aio.insecure_channel(rig.target) as ch:
                for what, method, body, code, words in _raw_cases():
                    try:
                        if "Reflection" in method:      # a request stream
                            async for _ in ch.stream_stream(method)(iter([body]), timeout=30):
                                pass
                        else:
                            await ch.unary_unary(method)(body, timeout=30)
                    except grpc.aio.AioRpcError as exc:
                        out.append((what, exc, code, words))
                    else:
                        pytest.fail(f"{what}: accepted")
            return out

        for what, exc, code, words in asyncio.run(go()):
            details = exc.details()
            assert exc.code() == code, f"{what}: {exc.code()} {details}"
            assert "\n" not in details and len(details) < 400, f"{what}: {details[:500]!r}"
            for w in words:
                assert w in details, f"{what}: {w!r} not in {details!r}"
            corpus_table("call before authentication", what, f"{exc.code().name}: {details}", "-")
        log = rig.log("coordinator")
        assert "Traceback" not in log and max(len(line) for line in log.splitlines()) < 700
    finally:
        rig.close()


def test_calls_over_the_budget_wait_their_turn_within_limits():
    async def go():
        b = Budget(reserve_bytes=4 * MIB, max_bytes_per_address=9 * MIB, max_waiting_per_address=2, max_waiting=3)
        held = [await b.enter("ipv4:10.0.0.1:1"), await b.enter("ipv4:10.0.0.1:2")]
        waiters = [asyncio.ensure_future(b.enter(f"ipv4:10.0.0.1:{p}", wait_s=5)) for p in (3, 4)]
        await wait_until_async(lambda: dict(b.waiting), lambda w: w == {"10.0.0.1": 2}, what="two calls waiting")
        assert await b.enter("ipv4:10.0.0.1:5") is None, "a third waiter from one address is refused at once"
        b.received(held[0], 200)                 # a small message: room for one more
        first = await asyncio.wait_for(asyncio.shield(asyncio.wait(waiters, return_when="FIRST_COMPLETED")), 5)
        assert len(first[0]) == 1
        b.release(held[1])
        got = await asyncio.gather(*waiters)
        assert all(t is not None for t in got) and not b.waiting
        late = await b.enter("ipv4:10.0.0.1:6", wait_s=0.05)
        assert late is None, "no room came within its wait"
        f = b.figures()
        assert (f.admitted, f.refused, b.waited) == (4, 2, 3)

    asyncio.run(go())


def test_an_ipv6_64_shares_one_budget_and_ipv4_mapped_counts_as_ipv4():
    assert budget_key("ipv6:[2001:db8:1:2:aaaa::1]:5000") == budget_key("ipv6:[2001:db8:1:2:bbbb::9]:6000") \
        == "2001:db8:1:2::/64"
    assert budget_key("ipv6:[2001:db8:1:3::1]:5000") == "2001:db8:1:3::/64"
    assert budget_key("ipv6:[::1]:5000") == "::1"
    assert budget_key("ipv6:[::ffff:10.0.0.5]:5000") == budget_key("ipv4:10.0.0.5:1") == "10.0.0.5"
    assert budget_key("unix:/tmp/relay") == "unix:/tmp/relay"
    b = Budget(reserve_bytes=4 * MIB, max_bytes_per_address=8 * MIB)
    assert b.admit("ipv6:[2001:db8::1]:1") and b.admit("ipv6:[2001:db8::2]:1")
    assert b.admit("ipv6:[2001:db8::3]:1") is None, "a third address of the same /64"
    assert b.admit("ipv6:[2001:db8:0:1::3]:1") is not None, "another /64"


def test_a_call_that_never_sends_its_message_gives_its_room_back(tmp_path, corpus_table):
    """A slow-loris: calls that open and send nothing are ended after READ_TIMEOUT_S, and a Hello
    from the same address is answered afterwards."""
    rig = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False).create()
    try:
        rig.start_coordinator()
        rig.wait_ready()

        async def go():
            async with grpc.aio.insecure_channel(rig.target) as ch:
                silent = [ch.stream_stream("/shadowless.v1.NodeLink/Hello")() for _ in range(12)]
                codes = collections.Counter()
                details = ""
                for call in silent:        # never written to
                    try:
                        await asyncio.wait_for(call.read(), 60)
                    except grpc.aio.AioRpcError as exc:
                        codes[exc.code().name] += 1
                        if exc.code() == grpc.StatusCode.DEADLINE_EXCEEDED:
                            details = exc.details()
                hello = common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, client_nonce=auth.new_nonce(),
                                                role="node", slot="r0c0")
                call = ch.unary_unary("/shadowless.v1.NodeLink/Hello", request_serializer=lambda m: m.SerializeToString(),
                                      response_deserializer=common_pb2.HelloReply.FromString)
                reply = await call(hello, timeout=30)
                return codes, details, reply

        codes, details, reply = asyncio.run(go())
        assert set(codes) <= {"DEADLINE_EXCEEDED", "RESOURCE_EXHAUSTED"} and codes["DEADLINE_EXCEEDED"] >= 1, codes
        assert "sent no request within 5 s" in details
        assert reply.server_nonce, "the address's room came back"
        corpus_table("call before authentication", "a Hello stream that never sends its message", details, "-")
    finally:
        rig.close()
