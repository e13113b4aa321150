"""The calibrate and alignment jobs against the virtual room (the in-process RoomDriver), checked
against the room's ground truth: accuracy bounds, sequential vs multiplexed, constant captures,
resume, record/replay, every operator error, the alignment check, and 3D on the bust."""
from __future__ import annotations

import asyncio
import json
import math

import cv2
import numpy as np
import pytest

from bench.calibration import (
    board_albedo,
    landmarks_from_truth,
    make_rig,
    mesh_errors,
    mesh_vertex_errors,
    planar_errors,
    rig_slots,
    table_points_from_truth,
)
from imaging.calibration.planar import CharucoSpec, homography_difference
from imaging.calibration.points import write_points
from coordinator.calibration.stages import dots
from coordinator.camera import open_camera
from coordinator.jobs import JobError, Progress
from coordinator.rig import HomographyPose, ProjectionPose, Rig
from shadowless.room_driver import RoomDriver
from sim.mesh import Mesh as SimMesh
from sim.mesh import bust, save_mesh
from sim.room import Room
from sim.scene import load_layout, reference_scene

CONTENT = (1200, 600)


class Driver(RoomDriver):
    """The room's rig driver, counting the patterns jobs showed through it."""

    shows = 0

    async def show_patterns(self, images, **kwargs):
        self.shows += 1
        await super().show_patterns(images, **kwargs)


def calibrate(driver: RoomDriver, params: dict) -> dict:
    return asyncio.run(driver.run("calibrate", params))


def alignment(driver: RoomDriver, params: dict) -> dict:
    return asyncio.run(driver.run("alignment", params))


def progress(driver: RoomDriver) -> list[Progress]:
    return [e for e in driver.events if isinstance(e, Progress)]


def logs(driver: RoomDriver) -> list[str]:
    return [e for e in driver.events if isinstance(e, str)]


@pytest.fixture(scope="module")
def room():
    """The reference room at its default resolution (projectors 320x200, camera 648x486), sensor noise on."""
    return Room(reference_scene())


@pytest.fixture(scope="module")
def small_room():
    """A lower-resolution room for the flow tests (projectors 128x80, camera 389x292)."""
    return Room(reference_scene(projector_scale=0.1, camera_scale=0.15), seed=1)


@pytest.fixture(scope="module")
def points(room, tmp_path_factory):
    f = tmp_path_factory.mktemp("points") / "table.json"
    table_points_from_truth(room, f, click_noise_px=0.3)
    return str(f)


@pytest.fixture(scope="module")
def small_points(small_room, tmp_path_factory):
    f = tmp_path_factory.mktemp("points") / "table.json"
    table_points_from_truth(small_room, f, click_noise_px=0.3)
    return str(f)


def check_bound(room, rig, slots, *, rms=0.3, mx=1.0):
    out = {}
    for s in slots:
        pose = rig.slot(s).pose
        assert isinstance(pose, HomographyPose) and rig.slot(s).source == "calibration"
        e = planar_errors(room, s, pose.matrix, CONTENT)
        assert e[0] <= rms and e[1] <= mx, (s, e)
        out[s] = e
    return out


@pytest.fixture(scope="module")
def multiplexed_rig(room, points, tmp_path_factory):
    """Nine projectors (P9W: centre, corners, edge midpoints) calibrated in the multiplexed mode."""
    rig = make_rig(tmp_path_factory.mktemp("mux") / "rig", room, rig_slots(9))
    driver = Driver(room, rig)
    result = calibrate(driver, {"mode": "multiplexed", "table_points": points, "settle_s": 0})
    return rig, result, driver


def test_sequential_gray_codes_meet_the_planar_bound(room, points, multiplexed_rig, tmp_path):
    slots = ["r0c0", "r2c2"]          # a corner unit (strong keystone) and the centre one
    rig = make_rig(tmp_path / "rig", room, slots)
    driver = Driver(room, rig)
    result = calibrate(driver, {"mode": "sequential", "table_points": points, "settle_s": 0})
    errs = check_bound(room, rig, slots)
    assert max(e[0] for e in errs.values()) < 0.15
    assert result["mode"] == "sequential" and result["captures"] == 2 + 2 * 36 and not result["failed"]
    for s in slots:
        doc = json.loads((rig.path / "calibration" / f"{s}.json").read_text())
        assert doc["run"] == result["run"] and doc["points"] > 5000 and doc["rms_px"] < 0.3
        assert result["slots"][s]["rms_px"] == doc["rms_px"]
    stages = {(e.stage, e.item) for e in progress(driver)}
    assert {("exposure", ""), ("cameras", ""), ("gray codes", "r0c0"), ("gray codes", "r2c2"), ("projectors", "r2c2")} <= stages
    cams = json.loads((rig.path / "calibration" / "cameras.json").read_text())
    assert np.shape(cams["cameras"][0]["table_to_camera"]) == (3, 3)
    assert Rig(rig.path).slot("r0c0").pose is not None     # persisted: a restarted coordinator serves it
    # the multiplexed mode agrees with the sequential one on the same projectors
    mux_rig = multiplexed_rig[0]
    g = np.stack(np.meshgrid(np.arange(0, 1200, 8), np.arange(0, 600, 8)), -1).reshape(-1, 2).astype(float)
    for s in slots:
        rms, mx = homography_difference(mux_rig.slot(s).pose.matrix, rig.slot(s).pose.matrix, g)
        assert rms < 0.15 and mx < 0.5, (s, rms, mx)


def test_multiplexed_mode_meets_the_bound_with_captures_independent_of_the_projector_count(room, points, multiplexed_rig, tmp_path):
    rig9, result9, driver9 = multiplexed_rig
    check_bound(room, rig9, rig_slots(9))
    assert result9["captures"] == driver9.shows == driver9.captures <= 30
    assert all(d["points"] >= 60 for d in result9["slots"].values())
    assert any(e.stage == "coded dots" for e in progress(driver9))
    rig1 = make_rig(tmp_path / "rig1", room, rig_slots(1))
    result1 = calibrate(RoomDriver(room, rig1), {"mode": "multiplexed", "table_points": points, "settle_s": 0})
    check_bound(room, rig1, rig_slots(1))
    assert result9["captures"] == result1["captures"]      # constant in N (the bound asks <= 2x)


def test_an_interrupted_run_resumes_and_force_starts_afresh(small_room, small_points, tmp_path):
    slots = ["r1c1", "r3c3"]
    rig = make_rig(tmp_path / "rig", small_room, slots)

    class Interrupting(RoomDriver):
        limit = 2 + 30 + 3     # exposure, all of r1c1, then a few of r3c3

        async def show_patterns(self, images, **kwargs):
            if self.captures >= self.limit:
                raise asyncio.CancelledError()      # Ctrl-C on the operator's side cancels the job
            await super().show_patterns(images, **kwargs)

    params = {"mode": "sequential", "table_points": small_points, "settle_s": 0}
    interrupted = Interrupting(small_room, rig)
    with pytest.raises(asyncio.CancelledError):
        calibrate(interrupted, dict(params))
    assert interrupted.captures == Interrupting.limit
    assert rig.slot("r1c1").pose is not None and rig.slot("r3c3").pose is None    # saved as soon as done
    first = json.loads((rig.path / "calibration" / "r1c1.json").read_text())
    assert json.loads((rig.path / "calibration" / "run.json").read_text())["status"] == "interrupted"
    driver = RoomDriver(small_room, rig)
    result = calibrate(driver, dict(params))
    assert result["resumed"] and result["run"] == first["run"]
    assert result["captures"] == 2 + 30                     # exposure, then only r3c3 (28 patterns + 2 references)
    assert result["slots"]["r1c1"].get("resumed") and set(result["slots"]) == set(slots)
    assert any("already done in this run" in line for line in logs(driver))
    rev = rig.slot("r1c1").revision
    again = calibrate(RoomDriver(small_room, rig), {**params, "force": True})
    assert not again["resumed"] and again["run"] != first["run"] and again["captures"] == 2 + 2 * 30
    assert rig.slot("r1c1").revision == rev + 1


class ReplayDriver(RoomDriver):
    """Also opens recorded folders (what `--camera folder:DIR` does on a coordinator)."""

    def open_camera(self, spec):
        return open_camera(spec) if spec.startswith("folder:") else super().open_camera(spec)


def test_a_recorded_run_replays_to_the_same_poses(small_room, small_points, tmp_path):
    slots = ["r1c1", "r2c2", "r3c3"]
    live = make_rig(tmp_path / "live", small_room, slots)
    rec = tmp_path / "rec"
    params = {"mode": "multiplexed", "table_points": small_points, "settle_s": 0}
    res_live = calibrate(RoomDriver(small_room, live), {**params, "record": str(rec)})
    assert len(list((rec / "camera0").glob("*.png"))) == res_live["captures"]
    replay = make_rig(tmp_path / "replay", small_room, slots)
    replayer = ReplayDriver(small_room, replay)
    res_replay = calibrate(replayer, {**params, "cameras": [f"folder:{rec / 'camera0'}"]})
    assert replayer.captures == 0                            # not one capture from the room
    for s in slots:
        np.testing.assert_array_equal(replay.slot(s).pose.matrix, live.slot(s).pose.matrix)
    assert res_replay["captures"] == res_live["captures"]
    # a replay that asks for more captures than were recorded says so
    more = make_rig(tmp_path / "more", small_room, slots)
    with pytest.raises(JobError, match="ran out of images"):
        calibrate(ReplayDriver(small_room, more), {**params, "rounds": 6, "cameras": [f"folder:{rec / 'camera0'}"]})


def test_operator_errors_name_the_slot_or_the_camera(small_room, small_points, tmp_path):
    params = {"mode": "sequential", "table_points": small_points, "settle_s": 0}
    # a projector that is off: the others are still calibrated and saved
    rig = make_rig(tmp_path / "a", small_room, ["r1c1", "r1c3"])
    with pytest.raises(JobError) as err:
        calibrate(RoomDriver(small_room, rig, unpowered=("r1c3",)), dict(params))
    assert "calibrated 1 of 2" in str(err.value) and "projector r1c3 not seen by the camera" in str(err.value)
    assert rig.slot("r1c1").pose is not None and rig.slot("r1c3").pose is None
    # the same in the multiplexed mode
    rig = make_rig(tmp_path / "b", small_room, ["r1c1", "r1c3"])
    with pytest.raises(JobError, match="projector r1c3 not seen by the camera"):
        calibrate(RoomDriver(small_room, rig, unpowered=("r1c3",)), {**params, "mode": "multiplexed"})
    assert rig.slot("r1c1").pose is not None
    # too few decoded pixels (an operator's stricter minimum than this projector can give)
    rig = make_rig(tmp_path / "c", small_room, ["r2c2"])
    with pytest.raises(JobError, match=r"too few decoded pixels for r2c2 \(\d+ < 10000000\)"):
        calibrate(RoomDriver(small_room, rig), {**params, "min_pixels": 10_000_000})
    # camera over- and under-exposed
    rig = make_rig(tmp_path / "d", small_room, ["r2c2"])
    with pytest.raises(JobError, match=r"camera 0 over-exposed \(\d+ % of the pixels r2c2 lights are saturated\): lower the exposure"):
        calibrate(RoomDriver(small_room, rig, exposure=80.0), dict(params))
    with pytest.raises(JobError, match=r"camera 0 under-exposed .* raise the exposure"):
        calibrate(RoomDriver(small_room, rig, exposure=0.02), dict(params))
    # parameters and setup
    fresh = make_rig(tmp_path / "e", small_room, ["r2c2"])
    with pytest.raises(JobError, match="needs known points"):
        calibrate(RoomDriver(small_room, fresh), {"mode": "sequential"})
    far = tmp_path / "far.json"
    far.write_text(json.dumps({"points": [{"xy": [x, y], "pixel": [5000 + x, 10 + y]} for x, y in [(0, 0), (1, 0), (0, 1), (1, 1)]]}))
    with pytest.raises(JobError, match="4 known point.s. lie outside its 389x292 image"):
        calibrate(RoomDriver(small_room, fresh), {**params, "table_points": str(far)})
    with pytest.raises(JobError, match="unknown calibrate parameter"):
        calibrate(RoomDriver(small_room, rig), {**params, "colour": "red"})
    with pytest.raises(JobError, match="r2c2 not connected"):
        calibrate(RoomDriver(small_room, rig, offline=("r2c2",)), {**params, "slots": ["r2c2"]})
    with pytest.raises(JobError, match="not in rig"):
        calibrate(RoomDriver(small_room, rig), {**params, "slots": ["r9c9"]})
    with pytest.raises(JobError, match="cannot read mesh .*x.obj"):      # both modes calibrate a mesh
        calibrate(RoomDriver(small_room, rig), {**params, "mode": "multiplexed", "mesh": "x.obj"})
    bad = tmp_path / "bad.json"
    bad.write_text('{"points": [{"xy": [0, 0]}]}')
    with pytest.raises(JobError, match="needs pixel"):
        calibrate(RoomDriver(small_room, rig), {**params, "table_points": str(bad)})


def test_known_points_listed_in_the_rig_file(small_room, tmp_path):
    rig = make_rig(tmp_path / "rig", small_room, ["r2c2"])
    pts = table_points_from_truth(small_room, click_noise_px=0.3)[0]
    rows = ", ".join(f"[{x:.1f}, {y:.1f}, {u:.2f}, {v:.2f}]" for (x, y, _), (u, v) in zip(pts.xyz, pts.pixels))
    with open(rig.path / "rig.toml", "a") as f:
        f.write(f"\n[calibration]\nmode = \"sequential\"\nsettle_s = 0\ntable_points = [{rows}]\n")
    rig = Rig(rig.path)                       # the coordinator reads rig.toml; the extra table is calibration's
    result = calibrate(RoomDriver(small_room, rig), {})
    assert result["mode"] == "sequential"
    check_bound(small_room, rig, ["r2c2"])
    with open(rig.path / "rig.toml", "a") as f:
        f.write("colour = 1\n")
    with pytest.raises(JobError, match="unknown \\[calibration\\] key"):
        calibrate(RoomDriver(small_room, rig), {})


def test_projectors_short_of_coded_dots_get_a_retry_round_then_a_clear_error(small_room, small_points, tmp_path, monkeypatch):
    monkeypatch.setattr(dots, "MIN_COARSE_DOTS", 1000)     # no projector can show that many dots on the table
    rig = make_rig(tmp_path / "rig", small_room, ["r1c1", "r2c2"])
    driver = Driver(small_room, rig)
    with pytest.raises(JobError, match=r"too few dots decoded for r1c1 \(\d+ < 1000\)"):
        calibrate(driver, {"mode": "multiplexed", "table_points": small_points, "settle_s": 0})
    assert driver.shows == 2 + 20 + 20          # exposure, the coded round, and its retry for the two projectors
    assert any(e.stage == "coded dots (retry)" for e in progress(driver))


def test_a_charuco_board_maps_the_table_then_calibration_reuses_the_mapping(room, tmp_path):
    """The operator lays a board on the table, maps the table (--table-only), removes the board, calibrates."""
    board = {"squares_x": 11, "squares_y": 7, "square_mm": 80.0, "marker_mm": 60.0, "dictionary": "DICT_5X5_100",
             "origin_mm": [-440.0, 280.0]}
    albedo = board_albedo(room, CharucoSpec.from_dict(board))

    class BoardCamera:
        """The room's camera seeing the board's black and white squares."""

        supports_exposure = False

        def __init__(self, camera):
            self.camera = camera

        def capture(self, *, exposure=None):
            return self.camera.capture(exposure=exposure) * albedo[:, :, None]

        def close(self):
            self.camera.close()

    class BoardOnTable(RoomDriver):
        def open_camera(self, spec):
            return BoardCamera(super().open_camera(spec))

    slots = ["r0c0", "r2c2", "r4c4"]
    rig = make_rig(tmp_path / "rig", room, slots)
    mapped = calibrate(BoardOnTable(room, rig), {"charuco": board, "table_only": True, "settle_s": 0})
    assert mapped["slots"] == {} and mapped["captures"] == 2 and all(rig.slot(s).pose is None for s in slots)
    H = np.array(json.loads((rig.path / "calibration" / "cameras.json").read_text())["cameras"][0]["table_to_camera"])
    grid = np.array([[x, y] for x in np.linspace(-600, 600, 13) for y in np.linspace(-300, 300, 7)])
    assert homography_difference(H, room.truth.table_to_camera_homography(), grid)[0] < 0.1
    driver = RoomDriver(room, rig)                     # the board is gone
    calibrate(driver, {"mode": "multiplexed", "settle_s": 0})
    assert any("using the table mapping saved" in line for line in logs(driver))
    errs = check_bound(room, rig, slots)
    assert max(e[0] for e in errs.values()) < 0.1


def test_alignment_check_measures_residuals_and_finds_a_shifted_projector(room, multiplexed_rig):
    rig, _, _ = multiplexed_rig
    good = alignment(RoomDriver(room, rig), {"settle_s": 0})
    assert good["captures"] == 3 and set(good["slots"]) == set(rig_slots(9))
    for s, d in good["slots"].items():
        assert d["dots"] >= 0.9 * d["planned"] and d["rms_px"] < 0.15 and d["max_px"] < 0.6, (s, d)
    # shift one projector's image by 1.5 projector px to the right: the check must see it there
    victim = "r2c4"
    old = rig.slot(victim).pose.matrix
    shift = np.array([[1, 0, 1.5], [0, 1, 0], [0, 0, 1.0]])
    rig.update_slot(victim, pose=HomographyPose(shift @ old), source="test")
    try:
        bad = alignment(RoomDriver(room, rig), {"settle_s": 0})
    finally:
        rig.update_slot(victim, pose=HomographyPose(old), source="calibration")
    d = bad["slots"][victim]
    assert bad["worst_slot"] == victim and abs(d["mean_offset_px"][0] - 1.5) < 0.15 and abs(d["mean_offset_px"][1]) < 0.15
    assert all(v["rms_px"] < 0.15 for s, v in bad["slots"].items() if s != victim)
    img = cv2.imread(bad["heatmap"])
    assert img is not None and img.shape[1] == 600 and img.shape[0] == 300
    assert json.loads((rig.path / "calibration" / "alignment.json").read_text())["worst_slot"] == victim
    with pytest.raises(JobError, match="unknown alignment parameter"):
        alignment(RoomDriver(room, rig), {"colour": 1})
    with pytest.raises(JobError, match="rounds must be in 1..16"):
        alignment(RoomDriver(room, rig), {"rounds": 40})


# ---------------------------------------------------------------------- 3D
@pytest.fixture(scope="module")
def bust_room():
    return Room(reference_scene(surface="bust"))


@pytest.fixture(scope="module")
def bust_file(tmp_path_factory):
    f = tmp_path_factory.mktemp("mesh") / "bust.obj"
    save_mesh(bust(), f)
    return f


def test_3d_calibration_on_the_bust_meets_the_bound(bust_room, bust_file, tmp_path):
    slots = ["r1c1", "r2c2"]
    table_points_from_truth(bust_room, tmp_path / "table.json", click_noise_px=0.3)
    landmarks_from_truth(bust_room, tmp_path / "landmarks.json", count=20, click_noise_px=0.5)
    rig = make_rig(tmp_path / "rig", bust_room, slots)
    result = calibrate(RoomDriver(bust_room, rig), {
        "mesh": str(bust_file), "table_points": str(tmp_path / "table.json"),
        "landmarks": str(tmp_path / "landmarks.json"), "settle_s": 0})
    assert result["mode"] == "sequential" and result["surface"] == "mesh"
    for s in slots:
        pose = rig.slot(s).pose
        assert isinstance(pose, ProjectionPose) and pose.mesh.uvs.shape == (len(pose.mesh.vertices), 2)
        rms, mx, n = mesh_errors(bust_room, s, pose.matrix)
        assert n > 2000 and rms <= 1.0, (s, rms, mx)
        assert rms < 0.5
        assert pose.near_mm < 800 and pose.far_mm > 1400
    assert Rig(rig.path).slot(slots[0]).pose.mesh.mesh_id == rig.slot(slots[0]).pose.mesh.mesh_id
    # the alignment check on the object: small residuals, and a projector shifted by 1.5 px is seen as such
    good = alignment(RoomDriver(bust_room, rig), {"settle_s": 0})
    for s in slots:
        d = good["slots"][s]
        assert d["dots"] >= 30 and d["rms_px"] < 0.3, (s, d)
    pose = rig.slot(slots[1]).pose
    shifted = np.array([[1, 0, 1.5], [0, 1, 0], [0, 0, 1.0]]) @ pose.matrix
    rig.update_slot(slots[1], pose=ProjectionPose(shifted, pose.mesh, pose.near_mm, pose.far_mm), source="test")
    bad = alignment(RoomDriver(bust_room, rig), {"settle_s": 0})
    d = bad["slots"][slots[1]]
    assert bad["worst_slot"] == slots[1] and abs(d["mean_offset_px"][0] - 1.5) < 0.2 and abs(d["mean_offset_px"][1]) < 0.2, d
    assert bad["heatmaps"][0]["frame"] == "camera px" and cv2.imread(bad["heatmap"]).shape[:2] == (450, 600)   # the camera image, 600 px wide


def test_3d_calibration_registers_a_mesh_given_in_its_own_frame(bust_room, tmp_path):
    """The operator's mesh comes from a scan in its own coordinates: the landmarks register it."""
    a = math.radians(30)
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    t = np.array([120.0, -40.0, 15.0])
    b = bust()
    model = (b.vertices.astype(np.float64) - t) @ R          # world = R model + t
    save_mesh(SimMesh(model, b.faces, b.uvs), tmp_path / "scan.ply")
    table_points_from_truth(bust_room, tmp_path / "table.json", click_noise_px=0.3)
    landmarks_from_truth(bust_room, tmp_path / "landmarks.json", count=24, click_noise_px=0.5, model_transform=(R, t))
    assert json.loads((tmp_path / "landmarks.json").read_text())["frame"] == "model"
    rig = make_rig(tmp_path / "rig", bust_room, ["r2c2"])
    calibrate(RoomDriver(bust_room, rig), {
        "mesh": str(tmp_path / "scan.ply"), "table_points": str(tmp_path / "table.json"),
        "landmarks": str(tmp_path / "landmarks.json"), "settle_s": 0})
    pose = rig.slot("r2c2").pose
    # the registered mesh sits where the bust is (to a few mm: one ceiling camera, clicks with 0.5 px noise) ...
    assert np.abs(pose.mesh.vertices - b.vertices).max() < 15.0
    # ... and, camera, mesh and projector being calibrated consistently, every texture point lands where it should
    rms, mx, n = mesh_vertex_errors(bust_room, "r2c2", pose.matrix, pose.mesh.vertices)
    assert n > 1000 and rms <= 1.0 and rms < 0.5, (rms, mx)


LAYOUT = """
name = "bust seen by two cameras"
[table]
size = [1200, 600]
[mesh]
builtin = "bust"
[[projector]]
slot = "front"
position = [60, 480, 1300]
target = [0, 0, 250]
[[camera]]
position = [-550, 650, 1150]
target = [0, 0, 250]
exposure = 0.4
[[camera]]
position = [550, 650, 1150]
target = [0, 0, 250]
exposure = 0.4
"""


def test_3d_calibration_pools_several_cameras(tmp_path):
    """Three cameras in the paper; here two, on either side of the object: both feed correspondences."""
    (tmp_path / "room.toml").write_text(LAYOUT)
    room = Room(load_layout(tmp_path / "room.toml", projector_scale=0.2, camera_scale=0.2), seed=2)
    save_mesh(bust(), tmp_path / "bust.obj")
    write_points(tmp_path / "table.json", [s for i in (0, 1) for s in table_points_from_truth(room, camera=i, seed=i)])
    write_points(tmp_path / "landmarks.json", [s for i in (0, 1) for s in landmarks_from_truth(room, camera=i, count=20, seed=i)])
    rig = make_rig(tmp_path / "rig", room, ["front"])
    result = calibrate(RoomDriver(room, rig, cameras=2), {
        "mesh": str(tmp_path / "bust.obj"), "table_points": str(tmp_path / "table.json"),
        "landmarks": str(tmp_path / "landmarks.json"), "settle_s": 0})
    per_camera = result["slots"]["front"]["cameras"]
    assert set(per_camera) == {0, 1} and all(c["on_mesh"] > 1000 for c in per_camera.values()), per_camera
    assert [c["camera"] for c in result["camera_setup"]] == [0, 1]
    P = rig.slot("front").pose.matrix
    for cam in (0, 1):
        rms, mx, n = mesh_errors(room, "front", P, camera=cam)
        assert n > 1000 and rms < 0.5, (cam, rms, mx)
