"""Who may join: protocol version, rig token (both directions), slot names, TLS."""
from __future__ import annotations

import asyncio
import json
import subprocess

import grpc
import pytest

from shadowless.local import LocalRig
from coordinator.api import NodeState
from protos import auth, common_pb2, node_pb2, node_pb2_grpc
from protos.version import PROTOCOL_VERSION
from waits import wait_until, wait_until_async


def run(coro):
    return asyncio.run(coro)


def wait_for_log(rig: LocalRig, name: str, text: str, timeout: float = 60.0) -> str:
    """``name``'s log once it holds ``text`` (the failure shows the log's tail)."""
    return wait_until(lambda: rig.log(name), lambda log: text in log, what=f"{name} to log {text!r}",
                      timeout=timeout)


@pytest.fixture
def small_rig(tmp_path):
    r = LocalRig(["r0c0", "r0c1"], tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False).create()
    r.start_coordinator()
    r.wait_ready()
    yield r
    r.close()


@pytest.fixture(scope="module")
def quiet_rig(tmp_path_factory):
    """A coordinator without nodes, shared by the tests that only call it over gRPC: what each asks for
    is refused whatever the others did (a tampered proof, an unknown slot, a replayed nonce, a call
    without a session), so one coordinator start serves them all."""
    r = LocalRig(["r0c0", "r0c1"], tmp_path_factory.mktemp("quiet"), output_size=(32, 32), content_size=(32, 32),
                 mdns=False).create()
    r.start_coordinator()
    r.wait_ready()
    yield r
    r.close()


def test_wrong_protocol_version_gets_a_clear_refusal(small_rig):
    small_rig.start_node("r0c0", ["--protocol-version", str(PROTOCOL_VERSION + 1)])
    log = wait_for_log(small_rig, "node-r0c0", "protocol version mismatch")
    assert f"speaks shadowless protocol {PROTOCOL_VERSION + 1}" in log and f"speaks {PROTOCOL_VERSION}" in log

    async def refusals():
        async with await small_rig.client() as c:
            return [r.reason for r in (await c.status()).refusals]

    assert any("protocol version mismatch" in r for r in run(refusals()))
    assert small_rig.nodes["r0c0"].poll() is None, "a refused node keeps retrying (an upgrade heals it)"


def test_node_with_wrong_token_does_not_trust_the_coordinator(small_rig, tmp_path):
    bad = tmp_path / "bad-token"
    bad.write_text(auth.new_token())
    bad.chmod(0o600)
    small_rig.start_node("r0c0", ["--token-file", str(bad)])
    log = wait_for_log(small_rig, "node-r0c0", "could not prove it knows the rig token")
    assert "wrong token file" in log

    # the coordinator lists the node as refused next to its slot, with why (not as expected)
    async def refused():
        async with await small_rig.client() as c:
            st = await wait_until_async(c.status, lambda st: any(r.slot == "r0c0" for r in st.refusals),
                                        what="a refusal listed for r0c0")
            return [r for r in st.refusals if r.slot == "r0c0"], st

    mine, st = run(refused())
    assert mine and "rig token mismatch" in mine[0].reason and mine[0].peer == "127.0.0.1", st.refusals
    table = small_rig.run_cli(["status"])
    row = next(line for line in table.splitlines() if line.startswith("r0c0"))
    assert row.split()[1] == "refused", table
    assert "r0c0: refused from 127.0.0.1: rig token mismatch" in table, table
    node = next(n for n in json.loads(small_rig.run_cli(["status", "--json"]))["nodes"] if n["slot"] == "r0c0")
    assert node["state"] == "expected" and "rig token mismatch" in node["refusal"]["reason"]


def test_rogue_coordinator_cannot_capture_a_node(quiet_rig, tmp_path):
    """A node of one rig pointed at the coordinator of another (as a rogue mDNS advertisement would):
    that coordinator cannot prove the node's token, so the node never joins it. The rogue is the
    module's coordinator of another rig, whose tests ask it for nothing this node could change; the
    node's own rig needs no coordinator running for this."""
    own = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False).create()
    assert own.token != quiet_rig.token
    try:
        own.start_node("r0c0", ["--coordinator", f"127.0.0.1:{quiet_rig.port}"])
        wait_for_log(own, "node-r0c0", "could not prove it knows the rig token")

        async def rogue_slot():
            async with await quiet_rig.client() as c:
                return {n.slot: n.state for n in (await c.status()).nodes}["r0c0"]

        assert run(rogue_slot()) == NodeState.EXPECTED
    finally:
        own.close()


async def _join(port: int, token: bytes, slot: str, *, tamper: bool = False):
    async with grpc.aio.insecure_channel(f"127.0.0.1:{port}") as ch:
        stub = node_pb2_grpc.NodeLinkStub(ch)
        cn = auth.new_nonce()
        hello = await stub.Hello(common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, client_nonce=cn, role="node", slot=slot))
        proof = auth.client_proof(token, "node", hello.rig_id, slot, cn, hello.server_nonce)
        if tamper:
            proof = bytes(b ^ 1 for b in proof)
        login = common_pb2.LoginRequest(protocol_version=PROTOCOL_VERSION, role="node", slot=slot, client_nonce=cn,
                                        server_nonce=hello.server_nonce, client_proof=proof)
        return await stub.Join(node_pb2.JoinRequest(login=login, info=node_pb2.NodeInfo(hostname="test")))


def test_coordinator_refuses_a_node_without_the_token(quiet_rig):
    with pytest.raises(grpc.aio.AioRpcError) as err:
        run(_join(quiet_rig.port, quiet_rig.token, "r0c0", tamper=True))
    assert err.value.code() == grpc.StatusCode.UNAUTHENTICATED
    assert "rig token mismatch" in err.value.details() and "r0c0" in err.value.details()


def test_unknown_slot_is_refused_with_the_known_slots(quiet_rig):
    with pytest.raises(grpc.aio.AioRpcError) as err:
        run(_join(quiet_rig.port, quiet_rig.token, "r9c9"))
    assert err.value.code() == grpc.StatusCode.NOT_FOUND
    assert "r0c0, r0c1" in err.value.details()


def test_nonces_are_single_use(quiet_rig):
    async def replay():
        async with grpc.aio.insecure_channel(f"127.0.0.1:{quiet_rig.port}") as ch:
            stub = node_pb2_grpc.NodeLinkStub(ch)
            cn = auth.new_nonce()
            hello = await stub.Hello(common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, client_nonce=cn, role="node", slot="r0c0"))
            proof = auth.client_proof(quiet_rig.token, "node", hello.rig_id, "r0c0", cn, hello.server_nonce)
            login = common_pb2.LoginRequest(protocol_version=PROTOCOL_VERSION, role="node", slot="r0c0", client_nonce=cn,
                                            server_nonce=hello.server_nonce, client_proof=proof)
            await stub.Join(node_pb2.JoinRequest(login=login))
            await stub.Join(node_pb2.JoinRequest(login=login))

    with pytest.raises(grpc.aio.AioRpcError) as err:
        run(replay())
    assert "single use" in err.value.details()


def test_calls_without_a_session_are_refused(quiet_rig):
    async def go():
        async with grpc.aio.insecure_channel(f"127.0.0.1:{quiet_rig.port}") as ch:
            stub = node_pb2_grpc.NodeLinkStub(ch)
            async for _ in stub.Frames(node_pb2.StreamRequest()):
                pass

    with pytest.raises(grpc.aio.AioRpcError) as err:
        run(go())
    assert err.value.code() == grpc.StatusCode.UNAUTHENTICATED


def test_health_and_reflection_answer_generic_tools(quiet_rig):
    from grpc_health.v1 import health_pb2, health_pb2_grpc
    from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc

    async def go():
        async with grpc.aio.insecure_channel(f"127.0.0.1:{quiet_rig.port}") as ch:
            health = await health_pb2_grpc.HealthStub(ch).Check(health_pb2.HealthCheckRequest(service="shadowless.v1.NodeLink"))
            refl = reflection_pb2_grpc.ServerReflectionStub(ch)

            async def reqs():
                yield reflection_pb2.ServerReflectionRequest(list_services="")

            services = []
            async for resp in refl.ServerReflectionInfo(reqs()):
                services = [s.name for s in resp.list_services_response.service]
            return health.status, services

    status, services = run(go())
    assert status == health_pb2.HealthCheckResponse.SERVING
    assert {"shadowless.v1.NodeLink", "shadowless.v1.RigControl", "grpc.health.v1.Health"} <= set(services)


def test_tls_channel(tmp_path):
    key, cert = tmp_path / "key.pem", tmp_path / "cert.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=shadowless-test",
                    "-addext", "subjectAltName=DNS:shadowless-test,IP:127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)
    rig = LocalRig(["r0c0"], tmp_path / "tls", output_size=(32, 32), content_size=(32, 32), mdns=False,
                   extra_node_args={"r0c0": ["--tls-ca", str(cert), "--tls-server-name", "shadowless-test"]}).create()

    rig.coordinator = rig._spawn("coordinator", ["coordinator", "--rig", str(rig.rig_dir), "--listen", f"127.0.0.1:{rig.port}",
                                                 "--no-mdns", "--no-console", "--tls-cert", str(cert), "--tls-key", str(key)])
    try:
        rig.start_node("r0c0")

        async def go():
            from rigctl.link import Client

            async def connect():
                try:
                    return await Client.connect(f"127.0.0.1:{rig.port}", rig.token, tls_ca=cert.read_bytes(),
                                                tls_server_name="shadowless-test")
                except Exception as exc:       # not listening yet; the failure shows the last one
                    return exc

            c = await wait_until_async(connect, lambda r: not isinstance(r, Exception),
                                       what="a TLS client connected to the coordinator")
            async with c:
                await rig.wait_live(c, timeout=60)

        run(go())
        # a plaintext client cannot talk to the TLS coordinator
        with pytest.raises(grpc.aio.AioRpcError):
            run(asyncio.wait_for(_join(rig.port, rig.token, "r0c0"), 10))
    finally:
        rig.close()


def test_a_second_node_for_a_taken_slot_is_refused_and_the_first_keeps_it(small_rig):
    """Two node processes started for one slot on one machine: the second takes the slot once
    (it could be a restart), the first is then refused when it comes back for it, and the slot
    stays with the second instead of changing hands forever. The first asks again 1 s after a
    refusal (an operator's node waits 10 s: a test hook), so its second refusal comes without that wait."""
    first = small_rig.start_node("r0c0", ["--refusal-backoff-s", "1"])
    wait_for_log(small_rig, "node-r0c0", "joined rig")
    twin = small_rig._spawn("node-r0c0-twin", small_rig.node_args("r0c0"))
    try:
        wait_for_log(small_rig, "node-r0c0-twin", "joined rig")
        log = wait_for_log(small_rig, "node-r0c0", "is taken by the live node")
        assert f"pid {twin.pid}" in log and "another --slot" in log

        async def holder(refusals: int = 1):
            """The slot's node and the count of refusals for it being taken, once that count is reached."""
            async with await small_rig.client() as c:
                st = await wait_until_async(c.status, lambda st: taken(st) >= refusals,
                                            what=f"{refusals} refusals of r0c0 as taken")
                (n,) = [n for n in st.nodes if n.slot == "r0c0"]
                return n, taken(st)

        def taken(st) -> int:
            return sum(r.count for r in st.refusals if r.slot == "r0c0" and "is taken by the live node" in r.reason)

        node, count = run(holder())
        assert node.pid == twin.pid
        joins = node.joins
        # the refused node retries (slowly): once that retry was refused too, nothing changed hands
        node, _ = run(holder(count + 1))
        assert (node.pid, node.joins) == (twin.pid, joins)
        assert first.poll() is None and twin.poll() is None
    finally:
        twin.terminate()
        twin.wait(30)


def test_a_live_slot_is_not_given_to_another_machine_until_its_node_goes_silent(tmp_path):
    """Coordinator rules, on an injected clock: another machine is refused while the holder is
    heard from; a restart on the holder's machine takes over; the process it replaced is refused;
    anyone takes a silent slot."""
    from coordinator.rig import Rig, grid_slots, init_rig
    from coordinator.app import CoordinatorApp
    from coordinator.errors import Refusal, RefusalKind
    from coordinator.sessions import NodeInfo, Report

    rig = Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 1), width=32, height=32))
    now = [1_000_000_000]

    async def go():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False, clock_ns=lambda: now[0]).coordinator
        a = NodeInfo(hostname="pi-a", pid=10, host_boot_id="boot-a")
        held = coord.join(slot="r0c0", info=a, peer="10.0.0.2:5000")
        with pytest.raises(Refusal) as refused:
            coord.join(slot="r0c0", info=NodeInfo(hostname="pi-b", pid=10, host_boot_id="boot-b"), peer="10.0.0.3:5000")
        assert refused.value.kind == RefusalKind.CONFLICT
        assert "10.0.0.2:5000 (pi-a, pid 10)" in refused.value.message
        assert not held.closed and coord.by_slot["r0c0"] is held
        assert any("is taken" in r.reason for r in coord.status().refusals)

        again = coord.join(slot="r0c0", info=a, peer="10.0.0.2:5001")           # the same process rejoins
        restart = coord.join(slot="r0c0", info=NodeInfo("pi-a", 11, "boot-a"), peer="10.0.0.2:5002")
        assert again.closed and coord.by_slot["r0c0"] is restart
        with pytest.raises(Refusal):                                         # the replaced process
            coord.join(slot="r0c0", info=a, peer="10.0.0.2:5003")

        now[0] += rig.config.lost_after_ms * 1_000_000 // 2
        coord.on_report(restart, Report())                                       # heard from: still held
        with pytest.raises(Refusal):
            coord.join(slot="r0c0", info=NodeInfo("pi-b", 10, "boot-b"), peer="10.0.0.3:5001")
        now[0] += rig.config.lost_after_ms * 1_000_000 + 1
        taken = coord.join(slot="r0c0", info=NodeInfo("pi-b", 10, "boot-b"), peer="10.0.0.3:5002")
        assert restart.closed and coord.by_slot["r0c0"] is taken

    run(go())
