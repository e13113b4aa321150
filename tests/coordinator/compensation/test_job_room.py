"""The compensation jobs in the virtual room (in-process, through shadowless.room_driver.RoomDriver
and bench.compensation_room's kit): responses against the room's gamma, the measured L against its
ground-truth transport, resume and fingerprints, the quality ordering of none / baseline / ours,
sequences, brightness matching, refusals.

The tests of this module share one calibrated 4-projector rig and run in file order."""
from __future__ import annotations

import asyncio
import json

import numpy as np
import pytest
import scipy.sparse as sp

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import demo_image, points_doc, truth_transport
from imaging.compensation.geometry import EDGE_WARNING, camera_target, inscribed_region, psf_radius
from coordinator.compensation.image_param import encode_image_array, prepare_image
from imaging.compensation.quality import quality
from imaging.compensation.response import brightness_scale
from imaging.compensation.solver import objective, solve
from coordinator.compensation.store import load_stored_response, response_path
from imaging.compensation.transport import load_transport, transport_error
from coordinator.jobs import JobError
from coordinator.rig import Content, HomographyPose, Mesh, ProjectionPose
from shadowless.room_driver import RoomCamera, RoomDriver
from sim.room import Room
from sim.scene import reference_scene

SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]
CONTENT = (300, 150)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=1)
    rig = make_rig(tmp_path_factory.mktemp("comp") / "rig", room, SLOTS, content_size=CONTENT)
    driver = RoomDriver(room, rig)
    asyncio.run(driver.run("calibrate", {"mode": "multiplexed", "settle_s": 0.0,
                                         "table_points": points_doc(table_points_from_truth(room))}))
    return room, rig, driver


def run(driver: RoomDriver, kind: str, params: dict) -> dict:
    return asyncio.run(driver.run(kind, params))


def stored_response(rig, slot: str):
    return load_stored_response(response_path(rig, slot), None)


def test_response_fits_each_projector_and_linearises_the_rig(setup):
    room, rig, driver = setup
    c0 = driver.captures
    out = run(driver, "response", {"settle_s": 0.0})
    # one shared black, per projector a white and two frames of 4x4 patches, then 6 linearity levels
    assert driver.captures - c0 == 1 + len(SLOTS) * 3 + 6 == out["captures"]
    for s in SLOTS:
        resp, doc = stored_response(rig, s)
        truth = room.truth.projector(s)
        curve_err = np.abs(resp.curve - resp.levels[None, :] ** truth.gamma[:, None]).max()
        assert curve_err < 0.02, (s, curve_err)
        assert np.allclose(resp.gamma, truth.gamma, atol=0.03)
        lut = rig.slot(s).lut
        assert lut is not None and lut.shape == (3, 1024) and rig.slot(s).source == "response"
        assert doc["patches"] >= 25
    lin = out["linearity"]
    assert lin["linear"] and lin["max_error"] < 0.01, lin
    assert out["brightness"]["gain"] == 1.0 and out["brightness"]["headroom"] > 3.5
    # a second run keeps the measured responses (only the linearity check captures)
    c0 = driver.captures
    again = run(driver, "response", {"settle_s": 0.0})
    assert driver.captures - c0 == 6 and all(d["resumed"] for d in again["slots"].values())
    # frames: every pattern captured and averaged that many times (a changed option measures again)
    c0 = driver.captures
    avg = run(driver, "response", {"settle_s": 0.0, "slots": SLOTS[:1], "frames": 2})
    assert driver.captures - c0 == 2 * (1 + 3 + 6) == avg["captures"] and not avg["slots"][SLOTS[0]]["resumed"]
    resp, _ = stored_response(rig, SLOTS[0])
    assert np.allclose(resp.gamma, room.truth.projector(SLOTS[0]).gamma, atol=0.03)


def test_transport_matches_the_rooms_truth_and_is_reused(setup):
    room, rig, driver = setup
    c0 = driver.captures
    out = run(driver, "transport", {"settle_s": 0.0})
    # the patterns and the black; the first pattern at the camera's exposure and the black at the dots' longer one
    assert not out["reused"] and out["captures"] == out["patterns"] + 3 == driver.captures - c0
    assert out["dot_gain"] > 1.0 and out["patterns_captured_again"] == 0
    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    H = np.asarray(meta["content_to_camera"])
    assert out["patterns"] == out["spacing"] ** 2
    assert out["radius"] == psf_radius(H, [rig.slot(s).pose.matrix for s in SLOTS], CONTENT)
    assert meta["fingerprint"] == out["fingerprint"] and meta["content_size"] == list(CONTENT)
    truth = truth_transport(room.truth.transport, lambda s: room.truth.projector(s).black, rig, SLOTS)
    err = transport_error(L, truth)
    assert err < 0.03, err      # 0.016 here with the dots 8x longer than the white; 0.047 at the camera's exposure
    # the radius holds the light: the truth inside the measured windows is nearly all of it
    windows = sp.csr_matrix((np.ones(L.nnz, np.float32), L.indices, L.indptr), shape=L.shape)
    inside = np.sum(truth.multiply(windows).data.astype(np.float64) ** 2) / np.sum(truth.data.astype(np.float64) ** 2)
    assert inside > 0.999, inside
    assert out["edge_energy"] < EDGE_WARNING
    # unchanged rig: reused without a capture
    c0 = driver.captures
    assert run(driver, "transport", {"settle_s": 0.0})["reused"] and driver.captures == c0
    # a changed gain changes what L describes: measured again (and force always measures)
    rig.update_slot(SLOTS[0], gain=0.99)
    assert not run(driver, "transport", {"settle_s": 0.0})["reused"]
    rig.update_slot(SLOTS[0], gain=1.0)
    assert not run(driver, "transport", {"settle_s": 0.0, "force": True})["reused"]
    _, meta = load_transport(rig.path / "compensation" / "transport.npz")
    assert [p.name for p in (rig.path / "compensation").glob("black-*.npy")] == [meta["black_file"]]
    # options: only those the caller sets must match the stored measurement
    r, sp_ = meta["radius"], meta["spacing"]
    assert run(driver, "transport", {"settle_s": 0.0, "radius": r, "spacing": sp_, "frames": 1})["reused"]
    wider = run(driver, "transport", {"settle_s": 0.0, "radius": r + 1})
    assert not wider["reused"] and wider["radius"] == r + 1
    c0 = driver.captures
    assert run(driver, "transport", {"settle_s": 0.0})["radius"] == r + 1 and driver.captures == c0
    with pytest.raises(JobError, match="another radius"):
        run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT)), "radius": r, "measure": False,
                                   "persist": False})
    assert run(driver, "transport", {"settle_s": 0.0, "force": True})["radius"] == r


def test_compensation_orders_none_baseline_ours_and_persists_the_result(setup):
    room, rig, driver = setup
    image = demo_image(CONTENT)
    out = run(driver, "compensate", {"image": encode_image_array(image, "astronaut.png"), "evaluate": True,
                                     "baseline": True, "baseline_exposure": float(len(SLOTS)), "settle_s": 0.0,
                                     "max_iter": 120, "eval_frames": 8})
    q = out["quality"]
    assert out["transport"]["reused"]
    assert q["ours"]["psnr"] > q["none"]["psnr"] + 1.0, q
    assert q["ours"]["psnr"] >= q["baseline"]["psnr"] - 0.05, q
    assert q["predicted"]["ours"]["psnr"] > q["predicted"]["none"]["psnr"] + 2.0
    b = out["baseline"]
    assert b["slots"] == sorted(SLOTS) and b["captures_per_projector"] == out["transport"]["patterns"]
    assert b["captures"] == len(SLOTS) * b["captures_per_projector"] + 1
    for s in SLOTS:
        Li, _ = load_transport(rig.path / "compensation" / "baseline" / f"{s}.npz")
        one = truth_transport(room.truth.transport, lambda k: room.truth.projector(k).black, rig, [s])
        assert transport_error(Li, one) < 0.1
    # the result is the rig's content (float32, what the room shows now) and its figures are stored
    assert rig.content is not None and rig.content.image.dtype == np.float32
    assert rig.content.image.shape == (CONTENT[1], CONTENT[0], 3)
    assert 0.0 <= rig.content.image.min() and rig.content.image.max() <= 1.0
    assert driver.shown is rig.content
    d = rig.path / "compensation"
    stored = json.loads((d / "result.json").read_text())     # the result as returned, but for where it went
    assert stored.pop("finished_at") > 0
    assert stored == {k: v for k, v in json.loads(json.dumps(out)).items() if k != "content"}
    assert out["content"].startswith("shown on every projector")
    assert (d / "quality.png").stat().st_size > 1000
    shows = q["picture_shows"]       # the picture's crop and difference images, from the float captures
    assert set(shows["mean_error"]) == {"none", "baseline", "ours"}
    assert shows["mean_error"]["ours"] < shows["mean_error"]["none"]
    x0, y0, x1, y1 = shows["window_camera_px"]
    assert q["region"]["x"][0] <= x0 < x1 <= q["region"]["x"][1] and q["region"]["y"][0] <= y0 < y1 <= q["region"]["y"][1]
    assert out["solve"]["objective"] < out["solve"]["initial_objective"]


def test_with_no_image_the_image_the_rig_shows_is_compensated(setup):
    """From the console: show an image, then compensate it (never an already compensated one)."""
    room, rig, driver = setup
    rig.set_content(Content(demo_image(CONTENT), name="compensated card.png"))
    with pytest.raises(JobError, match="already compensated: show the original again first"):
        run(driver, "compensate", {"measure": False})
    rig.set_content(Content(demo_image(CONTENT), name="card.png"))
    out = run(driver, "compensate", {"measure": False, "max_iter": 20, "persist": False})
    assert out["image"] == "card.png" and out["solve"]["objective"] < out["solve"]["initial_objective"]
    # --est-tol: the extrapolated rule stops the solve near the optimum, before the plain tolerance would
    full = run(driver, "compensate", {"measure": False, "max_iter": 2000, "persist": False})["solve"]
    fast = run(driver, "compensate", {"measure": False, "max_iter": 2000, "est_tol": 0.005, "persist": False})["solve"]
    assert fast["reason"] == "extrapolated" and fast["converged"] and fast["iterations"] < full["iterations"]
    assert full["penalised_objective"] <= fast["penalised_objective"] <= 1.01 * full["penalised_objective"]


def test_sequence_is_compensated_with_warm_starts_and_played(setup):
    room, rig, driver = setup
    wide = demo_image((CONTENT[0] + 8, CONTENT[1]))
    frames = [encode_image_array(np.ascontiguousarray(wide[:, k:k + CONTENT[0]]), f"f{k}.png") for k in range(0, 8, 2)]
    out = run(driver, "compensate_sequence", {"frames": frames, "iterations": 3, "first_iterations": 40, "fps": 30})
    assert out["frames"] == 4 and out["play"]["frames_sent"] == 4
    assert out["ms_per_frame_mean"] < out["ms_first_frame"]
    played = driver.played
    assert len(played) == 4 and played[0].dtype == np.uint16
    # the last frame, warm-started, beats the same 3 iterations from the uncompensated start and the
    # uncompensated image itself (predicted through the measured L)
    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    H = np.asarray(meta["content_to_camera"])
    cam = (meta["camera_size"][1], meta["camera_size"][0])
    content = prepare_image(np.ascontiguousarray(wide[:, 6:6 + CONTENT[0]]), CONTENT)
    s = np.float32(out["target_level"])
    target = camera_target(content, H, cam) * s
    region = inscribed_region(H, CONTENT, cam, margin=4)

    def psnr(x):
        c = (L @ np.asarray(x, np.float32).reshape(-1, 3)).reshape(target.shape)
        return quality(target[region] / s, c[region] / s).psnr

    last = played[-1].astype(np.float32) / 65535
    start = np.clip(content * np.float32(out["scale"]), 0, 1)
    cold = solve(L, target, x0=start, content_shape=(CONTENT[1], CONTENT[0]), max_iter=3, gap_tol=0, pg_tol=0)
    assert objective(L, last, target) < cold.objective
    assert psnr(last) > psnr(start) + 0.5


def test_brightness_matches_a_reference_projector(setup):
    room, rig, driver = setup
    out = run(driver, "response", {"settle_s": 0.0, "slots": SLOTS[1:], "reference": SLOTS[0]})
    responses = [stored_response(rig, s)[0] for s in SLOTS]
    ref = brightness_scale(responses[1:], responses[0])
    b = out["brightness"]
    assert b["gain"] == pytest.approx(ref.gain, rel=1e-5) and b["headroom"] == pytest.approx(ref.headroom, rel=1e-3)
    assert 0.25 < b["gain"] < 0.5
    assert all(rig.slot(s).gain == pytest.approx(ref.gain, rel=1e-5) for s in SLOTS[1:])
    assert out["linearity"]["linear"]
    # and a luminance the rig cannot reach leaves the gains at 1
    out = run(driver, "response", {"settle_s": 0.0, "reference": 10.0})
    assert out["brightness"]["gain"] == 1.0 and not out["brightness"]["reachable"]
    assert all(rig.slot(s).gain == 1.0 for s in SLOTS)


def test_refusals_name_what_to_do(setup, tmp_path):
    room, rig, driver = setup
    with pytest.raises(JobError, match="unknown transport parameter"):
        run(driver, "transport", {"radios": 3})
    rig.set_content(Content(demo_image(CONTENT), name="compensated card.png"))
    with pytest.raises(JobError, match="already compensated"):
        run(driver, "compensate", {})
    with pytest.raises(JobError, match="radius must be in 1..16"):
        run(driver, "transport", {"radius": 0})
    bare = make_rig(tmp_path / "bare", room, SLOTS, content_size=CONTENT)
    bdriver = RoomDriver(room, bare)
    with pytest.raises(JobError, match="or show one first"):     # no image given and nothing shown
        run(bdriver, "compensate", {})
    with pytest.raises(JobError, match="has no pose: calibrate"):
        run(bdriver, "transport", {"slots": SLOTS[:1]})
    bare.update_slot(SLOTS[0], pose=HomographyPose(rig.slot(SLOTS[0]).pose.matrix))
    with pytest.raises(JobError, match="run `shadowless calibrate` first"):
        run(bdriver, "transport", {"slots": SLOTS[:1]})
    mesh = Mesh("m", np.zeros((3, 3), np.float32), np.zeros((3, 2), np.float32), np.array([[0, 1, 2]], np.uint32))
    bare.update_slot(SLOTS[1], pose=ProjectionPose(np.hstack([np.eye(3), np.ones((3, 1))]), mesh))
    with pytest.raises(JobError, match="planar rigs"):
        run(bdriver, "transport", {"slots": SLOTS[:2]})
    with pytest.raises(JobError, match="not connected"):
        run(RoomDriver(room, rig, offline=SLOTS[:1]), "transport", {"slots": SLOTS[:2]})

    # a camera that cannot change its exposure (like most real ones): the baseline must average frames instead
    class FixedExposure(RoomDriver):
        def open_camera(self, spec: str) -> RoomCamera:
            camera = super().open_camera(spec)
            camera.supports_exposure = False
            return camera

    fixed = FixedExposure(room, rig)
    with pytest.raises(JobError, match="cannot change exposure"):
        run(fixed, "transport", {"baseline": True, "baseline_exposure": 4.0, "settle_s": 0.0})
    assert fixed.captures == 0
    # another set of projectors than the stored L was measured with, and no measuring allowed
    with pytest.raises(JobError, match="run `shadowless transport`"):
        run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT)), "measure": False,
                                   "slots": SLOTS[:2]})
