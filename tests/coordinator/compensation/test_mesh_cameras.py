"""L on a mesh rig from several cameras at once (the bust in the room with three cameras, through the bench kit's
RoomDriver): more texels seen than by either camera, each camera's rows of L what that camera alone measures,
the unseen texels reported and left uncompensated, and the solve's camera shares. Kept small (one projector, a
coarse camera and texture, a noiseless room so two measurements can be compared)."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401  (sp.linalg.norm)

from bench.compensation_bust import bust_room, make_bust_rig, mesh_transport_errors, truth_mesh_transport
from bench.compensation_room import demo_image
from coordinator.compensation.image_param import encode_image_array
from coordinator.compensation.mesh_cameras import camera_blocks, camera_shares, stacked_row_weights
from imaging.compensation.mesh_geometry import measured_texels, row_weights
from coordinator.compensation.mesh_rig import mesh_cameras
from imaging.compensation.transport import load_transport, transport_error
from coordinator.jobs import JobError
from shadowless.room_driver import RoomDriver

CONTENT = (128, 96)
SLOTS = ["r2c2"]
RADIUS = 4


def run(driver, kind: str, params: dict) -> dict:
    return asyncio.run(driver.run(kind, params))


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """The rig measured from camera 0 alone, camera 1 alone, then both (the stored L is the last); one radius for
    the three (by default each camera set takes the largest its cameras need)."""
    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2, noise=False, cameras=3)
    rig = make_bust_rig(tmp_path_factory.mktemp("bust3") / "rig", room, SLOTS, content_size=CONTENT, luts=True,
                        cameras=3)
    driver = RoomDriver(room, rig, cameras=3)
    out = {}
    for name, cams in (("0", [0]), ("1", [1]), ("01", [0, 1])):
        c0 = driver.captures
        out[name] = run(driver, "transport", {"settle_s": 0.0, "camera_indices": cams, "radius": RADIUS})
        out[name]["captures_taken"] = driver.captures - c0
        out[name]["L"] = load_transport(rig.path / "compensation" / "transport.npz")[0]
    return room, rig, driver, out


def test_two_cameras_see_more_and_each_measures_its_own_rows(measured):
    room, rig, driver, out = measured
    one, two = out["0"]["texture"], out["1"]["texture"]
    both = out["01"]["texture"]
    assert both["seen"] > max(one["seen"], two["seen"]) and both["measured"] > max(one["measured"], two["measured"])
    # every camera captures every pattern: (patterns + white + black + the first pattern at the white's exposure
    # + black at the dots' longer one) per camera, whatever the projectors
    assert out["01"]["captures"] == out["01"]["captures_taken"] == 2 * (out["01"]["patterns"] + 4)
    assert out["01"]["dot_gain"] > 1.0
    assert both["per_camera"] == [{"camera": 0, "seen": one["seen"], "measured": one["measured"]},
                                  {"camera": 1, "seen": two["seen"], "measured": two["measured"]}]
    assert both["seen"] == one["seen"] + two["seen"] - both["seen_by"]["2"]
    L0, L1, L01 = out["0"]["L"], out["1"]["L"], out["01"]["L"]
    assert L01.shape == (L0.shape[0] + L1.shape[0], L0.shape[1])
    top, bottom = camera_blocks(L01, 2)
    m0, m1 = measured_texels(top), measured_texels(bottom)
    np.testing.assert_array_equal(m0, measured_texels(L0))              # the same texels measured in each camera
    np.testing.assert_array_equal(m1, measured_texels(L1))
    assert both["measured"] == int(np.count_nonzero(m0 | m1))
    # a texel only camera 0 sees: its column is camera 0's own measurement, nothing in camera 1's rows; and
    # symmetrically
    errs, truth_errs = [], []
    for c, only, block, alone, empty in ((0, m0 & ~m1, top, L0, bottom), (1, m1 & ~m0, bottom, L1, top)):
        assert only.sum() > 50
        cols = np.flatnonzero(only)
        norm = sp.linalg.norm(alone.tocsc()[:, cols], axis=0)
        cols = cols[norm >= np.median(norm)]                # the lit half: tails of dim columns are relatively large
        err = transport_error(sp.csr_matrix(block.tocsc()[:, cols]), sp.csr_matrix(alone.tocsc()[:, cols]))
        errs.append(err)
        truth = sp.csr_matrix(truth_mesh_transport(room, rig, SLOTS, camera=c).tocsc()[:, cols])
        truth_errs.append([transport_error(sp.csr_matrix(m.tocsc()[:, cols]), truth) for m in (block, alone)])
        assert sp.csc_matrix(empty)[:, cols].nnz == 0
    # the two measurements of a camera differ a little (2 % in camera 0, 11 % in camera 1, noiseless: the two
    # schedules light other dots together, and in camera 1's side view the light a dot spills far from its texel
    # -- one projector from above, defocused at its silhouette of the bust -- falls into other windows) and are
    # equally close to the room's truth
    assert errs[0] < 0.05 and errs[1] < 0.2, errs
    for combined, own in truth_errs:
        assert combined < own + 0.01, truth_errs
    # and both blocks against the room's truth in each camera, each over the texels it measured (an independent
    # check; what is left is mostly light that lands far from its texel in the oblique camera: a dot near the
    # projector's silhouette of the bust spills, defocused, onto the table behind it)
    errs = mesh_transport_errors(L01, [truth_mesh_transport(room, rig, SLOTS, camera=c) for c in (0, 1)])
    assert errs["per_camera"][0] < 0.07 and errs["per_camera"][1] < 0.14 and errs["stacked"] < 0.1, errs


def test_unseen_texels_are_reported_and_left_uncompensated(measured):
    room, rig, driver, out = measured
    tex = out["01"]["texture"]
    assert tex["seen_by"]["0"] == tex["unseen"] > 0 and sum(tex["seen_by"].values()) == tex["on_mesh"]
    res = run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT), "a.png"), "measure": False,
                                     "camera_indices": [0, 1], "radius": RADIUS, "evaluate": True, "eval_frames": 1,
                                     "settle_s": 0.0, "max_iter": 40})
    t = res["texture"]
    # (one projector straight above lights little of the sides camera 1 sees: columns without light are not solved)
    assert t["unseen"] == tex["unseen"] and t["compensated"] > 0 and t["uncompensated"] >= t["unseen"]
    assert t["compensated"] + t["uncompensated"] == t["on_mesh"]
    q = res["quality"]
    assert len(q["ours"]["per_camera"]) == 2 and sum(c["pixels"] for c in q["ours"]["per_camera"]) == q["ours"]["pixels"]
    assert q["predicted"]["ours"]["psnr"] > q["predicted"]["none"]["psnr"]
    x = rig.content.image
    start = np.clip(demo_image(CONTENT).astype(np.float32) / 255 * np.float32(res["none_scale"]), 0, 1)
    kept = (~measured_texels(out["01"]["L"])).reshape(CONTENT[1], CONTENT[0])
    cams = mesh_cameras(rig, SLOTS, [0, 1])
    kept &= cams.on_mesh.reshape(kept.shape)
    assert np.abs(x[kept] - start[kept]).max() < 1e-6
    with pytest.raises(JobError, match="run `shadowless transport`"):         # L of other cameras is not reused
        run(driver, "compensate", {"image": encode_image_array(demo_image(CONTENT)), "measure": False,
                                   "camera_indices": [0, 2], "radius": RADIUS})


def test_camera_shares_and_weights(measured):
    room, rig, driver, out = measured
    L = out["01"]["L"]
    cams = mesh_cameras(rig, SLOTS, [0, 1])
    m = [measured_texels(b) for b in camera_blocks(L, 2)]
    share = camera_shares(cams, m)
    assert share.shape == (2, CONTENT[0] * CONTENT[1]) and share.dtype == np.float32
    anyone = m[0] | m[1]
    np.testing.assert_allclose(share.sum(axis=0)[anyone], 1.0, atol=1e-6)
    assert not share[:, ~anyone].any() and not share[0][~m[0]].any() and not share[1][~m[1]].any()
    np.testing.assert_array_equal(share[0][m[0] & ~m[1]], 1.0)
    w = stacked_row_weights(cams, L, radius=int(out["01"]["radius"]))
    hc = cams.part_shape[0]
    assert w.shape == cams.camera_shape == (2 * hc, cams.part_shape[1]) and w.dtype == np.float32
    # brute force: each camera's cos x area, times the share of the texel under each pixel, over one median
    raws, divisor = [], None
    for g, mk in zip(cams.parts, m):
        raws.append(row_weights(g.view, mk, g.content_size, radius=int(out["01"]["radius"]),
                                unmeasured_at=g.texels.position[g.texels.visible & ~mk], normalise=False))
    divisor = np.median(np.concatenate([r[r > 0] for r in raws]))
    for k, (g, r) in enumerate(zip(cams.parts, raws)):
        ys, xs = np.nonzero(r)
        for y, x in list(zip(ys, xs))[::37]:
            t = int(round(float(g.view.y[y, x]))) * CONTENT[0] + int(round(float(g.view.x[y, x])))
            assert w[k * hc + y, x] == pytest.approx(r[y, x] * share[k][t] / divisor, rel=1e-5)
    # one camera: exactly its own normalised weights
    one = mesh_cameras(rig, SLOTS, [1])
    np.testing.assert_array_equal(stacked_row_weights(one, out["1"]["L"], radius=int(out["1"]["radius"])),
                                  row_weights(one.parts[0].view, measured_texels(out["1"]["L"]), one.content_size,
                                              radius=int(out["1"]["radius"]),
                                              unmeasured_at=one.parts[0].texels.position[
                                                  one.parts[0].texels.visible & ~measured_texels(out["1"]["L"])]))


def test_tails_beyond_the_core_are_averaged_per_camera(measured):
    """Windows wider than the core: each camera's tail is averaged over its own texels (a stacked image's rows
    hold one window per camera), every texel measured before still is, and what the wider windows add is a faint
    tail. Runs last: it measures the rig again."""
    room, rig, driver, out = measured
    wide = run(driver, "transport", {"settle_s": 0.0, "camera_indices": [0, 1], "radius": RADIUS + 1})
    assert wide["tails_averaged"] and wide["core"] == RADIUS and wide["radius"] == RADIUS + 1
    L = load_transport(rig.path / "compensation" / "transport.npz")[0]
    for block, narrow in zip(camera_blocks(L, 2), camera_blocks(out["01"]["L"], 2)):
        m = measured_texels(narrow)
        np.testing.assert_array_equal(measured_texels(block)[m], True)
        total, core = float(block.tocsc()[:, m].sum()), float(narrow.tocsc()[:, m].sum())
        assert core <= total < 1.1 * core, (core, total)
