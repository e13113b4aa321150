"""The transport and compensate jobs on a mesh rig (the bust in the virtual room, through the bench kit's
RoomDriver): L in texture space against the room's true transport, reuse, the weighted solve with its
unseen texels left alone, the chart edges padded, and the refusals. Kept small (one projector, a coarse camera
and texture)."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest
import scipy.sparse as sp

from bench.compensation_bust import bust_room, make_bust_rig, truth_mesh_transport
from bench.compensation_room import demo_image
from coordinator.compensation.image_param import encode_image_array
from imaging.compensation.exposure import DOT_GAIN_MAX
from coordinator.compensation.mesh_compensate import evaluation_exposure
from imaging.compensation.mesh_geometry import measured_texels
from imaging.compensation.texture_space import MeshCaster, padding_index
from imaging.compensation.transport import load_transport, transport_error
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose
from shadowless.room_driver import RoomCamera, RoomDriver

CONTENT = (128, 96)
SLOTS = ["r2c2"]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2)
    rig = make_bust_rig(tmp_path_factory.mktemp("bust") / "rig", room, SLOTS, content_size=CONTENT, luts=True)
    return room, rig, RoomDriver(room, rig)


def run(driver, kind: str, params: dict) -> dict:
    return asyncio.run(driver.run(kind, params))


def test_transport_in_texture_space_is_the_rooms_and_is_reused(setup):
    room, rig, driver = setup
    c0 = driver.captures
    out = run(driver, "transport", {"settle_s": 0.0})
    assert out["surface"] == "mesh" and not out["reused"]
    # the dot patterns; one white (the exposure: one projector does not reach the camera's full scale), its black;
    # the first pattern at that exposure, which sets the dots' longer one, and the black at that
    assert out["captures"] == out["patterns"] + 4 == driver.captures - c0 and out["patterns"] >= 16
    assert out["exposure"] == 1.0 and 0 < out["white_peak"] < 0.9
    assert 1.0 < out["dot_gain"] <= DOT_GAIN_MAX and out["patterns_captured_again"] < out["patterns"] / 4
    # by default the windows reach twice the PSF's core, the tail beyond it averaged over neighbouring texels
    assert out["tails_averaged"] and out["radius"] == 2 * out["core"] >= 2
    tex = out["texture"]
    assert tex["texels"] == CONTENT[0] * CONTENT[1] and 0 < tex["measured"] <= tex["seen"] < tex["on_mesh"]
    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    cols = measured_texels(L)
    truth = truth_mesh_transport(room, rig, SLOTS)
    err = transport_error(sp.csr_matrix(L.tocsc()[:, cols]), sp.csr_matrix(truth.tocsc()[:, cols]))
    # 0.045 here: the defocus's tail is in L, its noise averaged away, and the dots captured 11x longer than
    # the white (0.060 at the white's exposure)
    assert err < 0.053, err
    c0 = driver.captures
    again = run(driver, "transport", {"settle_s": 0.0})
    assert again["reused"] and driver.captures == c0


def test_compensation_solves_the_seen_texels_and_leaves_the_rest(setup):
    room, rig, driver = setup
    out = run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT), "a.png"), "measure": False,
                                     "evaluate": True, "eval_frames": 1, "settle_s": 0.0,
                                     "max_iter": 60})
    tex = out["texture"]
    assert tex["compensated"] + tex["uncompensated"] == tex["on_mesh"] and tex["compensated"] > 0
    assert tex["uncompensated_share"] == pytest.approx(tex["uncompensated"] / tex["on_mesh"], abs=1e-4)
    q = out["quality"]
    assert "window_camera_px" not in q["picture_shows"] and q["picture_shows"]["mean_error"]["none"] > 0
    assert (rig.path / "compensation" / "quality.png").stat().st_size > 1000
    # what the solver believed, through the measured L: ours closer to the target than the content itself
    assert q["predicted"]["ours"]["psnr"] > q["predicted"]["none"]["psnr"]
    assert q["region"]["visible_surface_pixels"] == q["ours"]["pixels"] > 100
    x = rig.content.image
    assert x.shape == (CONTENT[1], CONTENT[0], 3) and x.dtype == np.float32 and driver.shown is rig.content
    # texels of the mesh without a column in L keep the uncompensated start (the content at the none level);
    # the texels around the uv charts copy their nearest chart texel (edge padding)
    L, _ = load_transport(rig.path / "compensation" / "transport.npz")
    mesh = rig.slot(SLOTS[0]).pose.mesh
    with MeshCaster(mesh.vertices, mesh.uvs, mesh.faces) as caster:
        on_mesh = np.isfinite(caster.atlas(CONTENT)).all(axis=2)
    unseen = on_mesh & ~measured_texels(L).reshape(CONTENT[1], CONTENT[0])
    content = demo_image(CONTENT).astype(np.float32) / 255
    start = np.clip(content * np.float32(out["none_scale"]), 0, 1)
    assert np.abs(x[unseen] - start[unseen]).max() < 1e-6
    pad = padding_index(on_mesh)
    np.testing.assert_array_equal(x.reshape(-1, 3), x.reshape(-1, 3)[pad])


def test_refusals_on_a_mesh_rig(setup, tmp_path):
    room, rig, driver = setup
    mixed = make_bust_rig(tmp_path / "mixed", room, ["r2c2", "r1c1"], content_size=CONTENT)
    mixed.update_slot("r1c1", pose=HomographyPose(np.eye(3)))
    with pytest.raises(JobError, match="planar rigs \\(a table\\) or a mesh"):
        run(RoomDriver(room, mixed), "transport", {"settle_s": 0.0})
    (mixed.path / "calibration" / "cameras.json").write_text('{"cameras": [{"camera": 0, "size": [10, 10]}]}')
    with pytest.raises(JobError, match="was not posed in 3D"):
        run(RoomDriver(room, mixed), "transport", {"settle_s": 0.0, "slots": ["r2c2"]})
    with pytest.raises(JobError, match="run `shadowless transport`"):
        run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT)), "measure": False, "radius": 7})


def test_evaluation_exposure_keeps_the_white_within_the_cameras_range():
    white = np.array([[0.2, 1.4], [0.5, 3.0]], np.float32)
    black = np.full((2, 2, 3), 0.05, np.float32)
    region = np.array([[True, True], [True, False]])           # the 3.0 pixel is not scored
    e, peak = evaluation_exposure(white, black, region)
    assert peak == pytest.approx(1.45) and e == pytest.approx(0.9 / 1.45)
    assert evaluation_exposure(white * 0.1, black, region)[0] == 1.0      # in range: the camera's own exposure


def test_a_surface_brighter_than_the_camera_is_measured_and_scored_unclipped(tmp_path, monkeypatch):
    """The camera's exposure set far too high for the bust: transport and evaluation lower it for their captures,
    where a camera that cannot change its exposure captures clipped dots and images, is warned about, and
    scores far lower."""
    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2)
    params = {"image": encode_image_array(demo_image(CONTENT), "a.png"), "evaluate": True, "eval_frames": 1,
              "settle_s": 0.0, "max_iter": 20}
    rigs = [make_bust_rig(tmp_path / name, room, SLOTS, content_size=CONTENT, luts=True) for name in ("a", "b")]
    driver = RoomDriver(room, rigs[0], exposure=20.0)
    res = run(driver, "compensate", params)
    lowered = res["quality"]
    assert res["transport"]["white_peak"] > 1.5 and res["transport"]["exposure"] == pytest.approx(lowered["transport_exposure"], abs=1e-4)
    assert lowered["transport_exposure"] < 0.5 and lowered["exposure"] <= lowered["transport_exposure"]
    assert not any("clip" in str(e) for e in driver.events)
    monkeypatch.setattr(RoomCamera, "supports_exposure", False)
    fixed = RoomDriver(room, rigs[1], exposure=20.0)
    clipped = run(fixed, "compensate", params)["quality"]
    assert clipped["exposure"] == clipped["transport_exposure"] == 1.0
    assert any("full scale" in str(e) and "clip" in str(e) for e in fixed.events)
    for k in ("none", "ours"):
        assert lowered[k]["psnr"] > clipped[k]["psnr"] + 3.0, (k, lowered[k], clipped[k])
