"""The compensation jobs refuse in one line, before they allocate, what would not fit in memory: measuring the
light transport, the per-projector baseline's transports, the solve of ``compensate``, the frames' solver of
``compensate_sequence`` and ``compensate_video``, and the Gray-code captures of a sequential calibration. The
budget is set through ``SHADOWLESS_MEMORY_LIMIT`` (an absurdly small one is the same refusal an absurd size
meets on a real machine), on a small in-process room rig (2 projectors, 160x80 content). The tests of this
module share one rig and run in file order."""
from __future__ import annotations

import asyncio

import cv2
import numpy as np
import pytest

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import demo_image, points_doc
from coordinator.assets import AssetStore
from coordinator.compensation.image_param import encode_image_array
from imaging.compensation.memory_estimate import measure_bytes, transport_bytes
from imaging.compensation.transport import load_transport
from coordinator.jobs import JobError
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import reference_scene

SLOTS = ["r1c1", "r3c3"]
CONTENT = (160, 80)
ONE_LINE = r"^needs about \d+ MB for {what}[^,]*, 1 MB available \(SHADOWLESS_MEMORY_LIMIT=1M\); use .* \(or SHADOWLESS_MEMORY_LIMIT=off to try anyway\)$"


def run(driver: RoomDriver, kind: str, params: dict) -> dict:
    return asyncio.run(driver.run(kind, params))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    work = tmp_path_factory.mktemp("memory")
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=1)
    rig = make_rig(work / "rig", room, SLOTS, content_size=CONTENT)
    driver = RoomDriver(room, rig)
    run(driver, "calibrate", {"mode": "multiplexed", "settle_s": 0.0,
                              "table_points": points_doc(table_points_from_truth(room))})
    return work, rig, driver


def test_measuring_the_transport_is_refused_after_the_black_capture(setup, monkeypatch):
    work, rig, driver = setup
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", "1M")
    c0 = driver.captures
    with pytest.raises(JobError, match=ONE_LINE.format(what=r"the light transport of 160x80 content seen by a "
                                                       r"\d+x\d+ camera \(radius \d+\)")) as exc:
        run(driver, "transport", {"settle_s": 0.0})
    assert "\n" not in str(exc.value)
    assert driver.captures - c0 == 1          # the black capture only: no dot pattern was shown
    assert not (rig.path / "compensation" / "transport.npz").exists()
    # the same refusal for the jobs that would measure first
    with pytest.raises(JobError, match=ONE_LINE.format(what="the light transport of 160x80 content")):
        run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT)), "settle_s": 0.0})


def test_the_baseline_is_refused_when_only_its_transports_do_not_fit(setup, monkeypatch):
    work, rig, driver = setup
    run(driver, "transport", {"settle_s": 0.0})        # the machine's own budget: L is measured
    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    cw, ch = meta["content_size"]
    n, m, r = cw * ch, L.shape[0], int(meta["radius"])
    # room for one more measurement, not for it and the two projectors' L_i it keeps
    budget = measure_bytes(n, m, r) + transport_bytes(n, m, r)
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", str(budget))
    c0 = driver.captures
    with pytest.raises(JobError, match=r"^needs about \d+ MB for 2 per-projector baseline transports of 160x80 "
                                       r"content .*; use no --baseline, or a smaller content size"):
        run(driver, "transport", {"baseline": True, "settle_s": 0.0})
    assert driver.captures == c0    # refused before the baseline's first capture


def test_the_solves_are_refused_over_a_stored_transport(setup, monkeypatch):
    work, rig, driver = setup
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", "1M")
    image = encode_image_array(demo_image(CONTENT))
    with pytest.raises(JobError, match=ONE_LINE.format(what="the compensation solve over 160x80 content seen by a")):
        run(driver, "compensate", {"image": image, "measure": False})
    with pytest.raises(JobError, match=ONE_LINE.format(what="the frames' solver over 160x80 content")):
        run(driver, "compensate_sequence", {"frames": [image, image], "measure": False, "play": False})
    seq = work / "seq"
    seq.mkdir()
    for k in range(2):
        cv2.imwrite(str(seq / f"{k:03d}.png"), np.full((CONTENT[1], CONTENT[0], 3), 60 * k + 40, np.uint8))
    AssetStore(rig.path).add(seq, name="seq", fps=10, note=lambda _: None)
    with pytest.raises(JobError, match=ONE_LINE.format(what="the frames' solver over 160x80 content")):
        run(driver, "compensate_video", {"asset": "seq", "measure": False})
    assert AssetStore(rig.path).resolve("seq") and not [m for _, m in AssetStore(rig.path).list() if "compensated" in m.name]
    # with the check off the same solve runs
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", "off")
    out = run(driver, "compensate", {"image": image, "measure": False, "max_iter": 5, "persist": False})
    assert out["solve"]["iterations"] >= 1


def test_gray_code_calibration_is_refused_before_its_patterns(setup, monkeypatch, tmp_path):
    work, rig, driver = setup
    room = driver.room
    bare = make_rig(tmp_path / "bare", room, SLOTS, content_size=CONTENT)
    bdriver = RoomDriver(room, bare)
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", "1M")
    c0 = bdriver.captures
    with pytest.raises(JobError, match=ONE_LINE.format(what=r"the \d+ Gray-code captures of r1c1 from 1 camera\(s\) of "
                                                       r"\d+x\d+")):
        run(bdriver, "calibrate", {"mode": "sequential", "settle_s": 0.0,
                                   "table_points": points_doc(table_points_from_truth(room))})
    # the setup's captures, the white and the black; not one of the (at least 2 x 8) Gray-code patterns
    assert bdriver.captures - c0 < 8, bdriver.captures - c0
    assert bare.slot(SLOTS[0]).pose is None


def test_a_mesh_rigs_transport_is_refused_after_the_black_capture(tmp_path, monkeypatch):
    from bench.compensation_bust import bust_room, make_bust_rig

    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2)
    rig = make_bust_rig(tmp_path / "bust", room, ["r2c2"], content_size=(128, 96), luts=True)
    driver = RoomDriver(room, rig)
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", "1M")
    with pytest.raises(JobError, match=ONE_LINE.format(what=r"the light transport of 128x96 content seen by a \d+x\d+ "
                                                       r"camera \(radius \d+\)")):
        run(driver, "transport", {"settle_s": 0.0})
    assert not (rig.path / "compensation" / "transport.npz").exists()


def test_compensate_with_the_baseline_counts_its_transports(setup, monkeypatch):
    from imaging.compensation.memory_estimate import ridge_bytes, solve_bytes

    work, rig, driver = setup
    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    cw, ch = meta["content_size"]
    n, m, r = cw * ch, L.shape[0], int(meta["radius"])
    # room for ours alone, not for ours and the two projectors' L_i beside it
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", str(ridge_bytes(n, m, r) + solve_bytes(n, m + n, 3) + transport_bytes(n, m, r)))
    with pytest.raises(JobError, match=r"^needs about \d+ MB for the compensation solve with 2 per-projector baselines "
                                       r"over 160x80 content .*; use no --baseline, or a smaller content size"):
        run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT)), "measure": False,
                                   "baseline": True, "settle_s": 0.0})


def test_a_mesh_rigs_solve_and_baseline_are_refused_over_its_stored_transport(tmp_path, monkeypatch):
    from bench.compensation_bust import bust_room, make_bust_rig

    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2)
    rig = make_bust_rig(tmp_path / "bust", room, ["r2c2"], content_size=(128, 96), luts=True)
    driver = RoomDriver(room, rig)
    run(driver, "transport", {"settle_s": 0.0})
    monkeypatch.setenv("SHADOWLESS_MEMORY_LIMIT", "1M")
    image = encode_image_array(demo_image((128, 96)))
    with pytest.raises(JobError, match=ONE_LINE.format(what=r"the compensation solve over \d+ texels seen by \d+ "
                                                       r"camera pixels \(\d+ non-zeros\)")):
        run(driver, "compensate", {"image": image, "measure": False})
    with pytest.raises(JobError, match=r"^needs about \d+ MB for 1 per-projector baseline transports over \d+ texels"
                                       r".*; use no --baseline"):
        run(driver, "transport", {"baseline": True, "settle_s": 0.0})
