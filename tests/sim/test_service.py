"""The room's gRPC services, called for real on 127.0.0.1."""
from __future__ import annotations

import threading
import time
from dataclasses import replace

import grpc
import numpy as np
import pytest

from protos import codec, room_pb2, room_pb2_grpc
from sim.link import RoomClient
from sim.errors import FrameError, UnknownSlotError
from sim.hand import Hand, HandPath
from sim.room import Room
from sim.scene import reference_scene
from sim.wire.service import RoomServerThread


def make_room() -> Room:
    return Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=7, noise=False)


@pytest.fixture
def served():
    room = make_room()
    with RoomServerThread(room) as server, RoomClient(server.address) as client:
        yield room, server, client


def test_describe_room_and_projectors(served):
    room, _, client = served
    d = client.describe()
    assert list(d.rig_slots) == room.slots
    assert [p.slot for p in d.projectors][:25] == room.slots and d.projectors[25].slot == "p1"
    assert not d.projectors[25].powered and d.projectors[0].powered
    assert (d.cameras[0].width, d.cameras[0].height, d.cameras[0].bits) == (324, 243, 12)
    assert d.surface == "table"
    assert client.projector_size("r3c1") == (160, 100)
    with pytest.raises(UnknownSlotError, match="no projector 'zz'"):
        client.projector_size("zz")


def test_display_then_capture_equals_the_room_in_process(served):
    _, _, client = served
    local = make_room()
    rng = np.random.default_rng(0)
    frames = {s: rng.integers(0, 256, (100, 160, 3), dtype=np.uint8) for s in ("r0c0", "r2c2", "r4c4")}
    assert client.display(frames, frame_id=5, swap_rig_ns=123) == 3
    got = client.capture()
    for s, f in frames.items():
        local.set_frame(s, f)
    np.testing.assert_array_equal(got.image, local.capture())
    assert got.frames == {s: (5, 123) for s in frames}
    assert got.late_slots == []
    half = client.capture(exposure=0.5)
    np.testing.assert_allclose(half.image, local.capture(exposure=0.5), atol=1e-7)


def test_capture_waits_for_frames_swapped_after_an_instant(served):
    _, _, client = served
    frame = np.full((100, 160, 3), 128, np.uint8)
    client.display({"r2c2": frame}, frame_id=1, swap_rig_ns=1_000)

    def later():
        # the capture must be waiting on the server before frame 2 arrives, and the server shows no sign
        # of a waiting capture that a test could wait for: only time puts the display after it
        time.sleep(0.4)
        client.display({"r2c2": frame}, frame_id=2, swap_rig_ns=2_000)

    t = threading.Thread(target=later)
    t.start()
    try:
        got = client.capture(not_before_rig_ns=2_000, timeout_ms=10_000)
    finally:
        t.join()
    assert got.frames["r2c2"] == (2, 2_000) and got.late_slots == []
    late = client.capture(not_before_rig_ns=3_000, timeout_ms=200)
    assert late.late_slots == ["r2c2"] and late.frames["r2c2"] == (2, 2_000)


def test_bad_frames_and_cameras_are_refused_with_reasons(served):
    _, server, client = served
    with pytest.raises(FrameError, match="is 320x200.*takes 160x100"):
        client.display({"r0c0": np.zeros((200, 320, 3), np.uint8)})
    with pytest.raises(FrameError, match="uint8"):
        client.display({"r0c0": np.zeros((100, 160, 3), np.float32)})
    with pytest.raises(UnknownSlotError, match="r5c5"):
        client.display({"r5c5": np.zeros((100, 160, 3), np.uint8)})
    with pytest.raises(UnknownSlotError, match="no camera 3"):
        client.capture(camera=3)
    with grpc.insecure_channel(server.address) as ch:
        stub = room_pb2_grpc.RoomStub(ch)
        bad = codec.encode_image(np.zeros((100, 160, 3), np.uint8))
        bad.data = bad.data[:-5]
        with pytest.raises(grpc.RpcError) as info:
            stub.Display(iter([room_pb2.DisplayedFrame(slot="r0c0", image=bad)]), timeout=10)
        assert info.value.code() == grpc.StatusCode.INVALID_ARGUMENT


def test_truth_service_matches_the_room(served):
    room, _, client = served
    local = make_room()
    np.testing.assert_allclose(client.projector_matrix("r1c3"), local.truth.projector("r1c3").P)
    t = client.projector_truth("p1")
    assert not t.powered and t.peak == pytest.approx(local.projector("p1").peak)
    c = client.camera_truth()
    assert (c.width, c.height, c.bits) == (324, 243, 12)
    hand = Hand(position=(50.0, -20.0), height=200.0, yaw_deg=15.0)
    assert client.set_occluders([hand]) == 7
    local.set_occluders([hand])
    np.testing.assert_array_equal(client.light_drop(), local.truth.light_drop())
    np.testing.assert_array_equal(client.occluder_mask(), local.truth.occluder_mask())
    np.testing.assert_array_equal(client.projector_coordinates("r0c1"), local.truth.projector_coordinates("r0c1"))
    T = client.transport("r0c1")
    L = local.truth.transport("r0c1")
    assert T.shape == L.shape and abs(T - L).max() == 0
    assert client.set_active(["r0c0", "p1"]) == ["r0c0", "p1"]
    assert room.active == ["r0c0", "p1"]
    with pytest.raises(UnknownSlotError):
        client.set_active(["nope"])
    client.set_occluders(path=HandPath.sweep((-200.0, 0.0), (200.0, 0.0), period=2.0))
    assert isinstance(room.occluders()[0], Hand)
    with pytest.raises(FrameError, match="pose"):
        client._call(client._truth.SetOccluders, room_pb2.SetOccludersRequest(hands=[room_pb2.HandSpec(pose="fist")]))


def test_health_reflection_and_truth_switch():
    from grpc_health.v1 import health_pb2, health_pb2_grpc
    from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc

    with RoomServerThread(make_room(), truth=False) as server, grpc.insecure_channel(server.address) as ch:
        health = health_pb2_grpc.HealthStub(ch)
        for name in ("", "shadowless.v1.Room"):
            assert health.Check(health_pb2.HealthCheckRequest(service=name), timeout=10).status == health_pb2.HealthCheckResponse.SERVING
        refl = reflection_pb2_grpc.ServerReflectionStub(ch)
        reply = next(refl.ServerReflectionInfo(iter([reflection_pb2.ServerReflectionRequest(list_services="")]), timeout=10))
        names = {s.name for s in reply.list_services_response.service}
        assert "shadowless.v1.Room" in names and "shadowless.v1.RoomTruth" not in names
        with pytest.raises(grpc.RpcError) as info:
            room_pb2_grpc.RoomTruthStub(ch).GetLightDrop(room_pb2.CameraRequest(), timeout=10)
        assert info.value.code() == grpc.StatusCode.UNIMPLEMENTED


def test_a_capture_exposure_is_relative_to_the_cameras_own():
    """A camera opened up 4x: no exposure asked is its own, 0.5 is half of it (2x the room's unit), as the
    coordinator's jobs ask for a share of the camera's exposure whatever the camera is set to."""
    scene = reference_scene(projector_scale=0.125, camera_scale=0.125)
    scene = replace(scene, cameras=(replace(scene.cameras[0], exposure=4.0),))
    room, local = Room(scene, seed=7, noise=False), Room(scene, seed=7, noise=False)
    frame = np.full((100, 160, 3), 200, np.uint8)
    with RoomServerThread(room) as server, RoomClient(server.address) as client:
        client.display({"r2c2": frame}, frame_id=1, swap_rig_ns=1)
        local.set_frame("r2c2", frame)
        own, half = client.capture().image, client.capture(exposure=0.5).image
    np.testing.assert_array_equal(own, local.capture())
    np.testing.assert_allclose(half, local.capture(exposure=2.0), atol=1e-7)
    assert 0 < float(half.max()) < float(own.max())
