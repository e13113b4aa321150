"""The compensation numerics on the virtual room: response/LUT of a projector and its light transport.

The room is an independent physical simulation; its ground truth (response gamma, transport
matrix) is read only here, to check what the numerics recover from captures.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from imaging.compensation import (
    DotGrid,
    capture_means,
    fit_response,
    grey_levels,
    inverse_lut,
    response_mask,
    transport_error,
    transport_from_captures,
    verify_linearity,
)
from protos.spaces import lut_lookup

from sim import room as sim_room
from sim import scene as sim_scene

SLOT = "r1c3"


@pytest.fixture(scope="module")
def room():
    room = sim_room.Room(sim_scene.reference_scene(projector_scale=0.125, camera_scale=0.125), noise=False)
    room.set_active([SLOT])
    return room


def show(room, frame: np.ndarray, exposure: float) -> np.ndarray:
    room.set_frame(SLOT, frame)
    return room.capture(exposure=exposure)


def test_response_lut_and_linearity_in_the_room(room):
    w, h = room.projector_size(SLOT)
    exposure = 20 * room.truth.camera().exposure  # one projector of 25: open up the camera
    levels = grey_levels(17)
    caps = [show(room, np.full((h, w, 3), round(255 * v), np.uint8), exposure) for v in levels]
    mask = response_mask(caps[-1], caps[0])
    assert mask.mean() > 0.05
    resp = fit_response(levels, capture_means(caps, mask=mask))
    truth = room.truth.projector(SLOT)
    assert np.allclose(resp.gamma, truth.gamma, atol=0.01)
    lut = inverse_lut(resp, entries=1024)
    y = np.linspace(0, 1, 11)
    frames = [np.broadcast_to(lut_lookup(lut, np.full((1, 1, 3), v)), (h, w, 3)).copy() for v in y]
    after = capture_means([show(room, f, exposure) for f in frames], mask=mask)
    report = verify_linearity(y, after, tolerance=0.01)
    assert report.linear, report
    before = capture_means([show(room, np.full((h, w, 3), round(255 * v), np.uint8), exposure) for v in y], mask=mask)
    assert not verify_linearity(y, before, tolerance=0.01).linear


def test_transport_measured_in_the_room_matches_its_truth(room):
    w, h = room.projector_size(SLOT)
    exposure = 20 * room.truth.camera().exposure
    # content = this projector's pixels; its pixels reach the camera through the table plane
    h_pc = room.truth.table_to_camera_homography() @ np.linalg.inv(room.truth.table_to_projector_homography(SLOT))
    h_pc /= h_pc[2, 2]
    grid = DotGrid(w, h, 5)
    black = show(room, np.zeros((h, w, 3), np.uint8), exposure)
    caps = (show(room, np.repeat(grid.pattern(k, value=255, dtype=np.uint8)[:, :, None], 3, axis=2), exposure)
            for k in range(len(grid)))
    measured = transport_from_captures(caps, black, grid=grid, homography=h_pc, radius=2)
    truth = room.truth.projector(SLOT)
    # the truth maps emitted luminance; the dots emit 1 - black above the black frame
    expected = room.truth.transport(SLOT) * (exposure / room.truth.camera().exposure) * float(np.mean(1 - truth.black))
    assert measured.shape == expected.shape
    err = transport_error(measured, expected)
    assert err < 0.01, err  # sensor quantisation only


def test_rig_transport_measured_with_all_projectors_at_once():
    """25 projectors show the same dot grid (each warped by its pose): S*S + 1 captures give L = sum L_i."""
    full = sim_room.Room(sim_scene.reference_scene(projector_scale=0.25, camera_scale=0.125), noise=False)
    truth = full.truth
    wc, hc = 200, 100  # content covering the table, 6 mm per pixel
    h_cc = truth.table_to_camera_homography() @ truth.content_to_table_homography((wc, hc))
    h_cc /= h_cc[2, 2]
    warps = {}
    for slot in full.slots:
        # each projector shows the content through its pose (nearest content pixel: 0/255 frames)
        w, h = full.projector_size(slot)
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        p = np.linalg.inv(truth.content_to_projector_homography(slot, (wc, hc))) @ np.stack(
            [u.ravel(), v.ravel(), np.ones(u.size)])
        x = np.rint(p[0] / p[2]).astype(np.int64)
        y = np.rint(p[1] / p[2]).astype(np.int64)
        ok = (x >= 0) & (x < wc) & (y >= 0) & (y < hc)
        warps[slot] = sp.csr_matrix((np.ones(ok.sum(), np.float32), (np.flatnonzero(ok), (y * wc + x)[ok])),
                                    shape=(w * h, wc * hc))

    def show_all(pattern: np.ndarray) -> np.ndarray:
        for slot, warp in warps.items():
            w, h = full.projector_size(slot)
            frame = np.rint(255 * (warp @ pattern.ravel())).astype(np.uint8).reshape(h, w)
            full.set_frame(slot, np.repeat(frame[:, :, None], 3, axis=2))
        return full.capture()

    grid = DotGrid(wc, hc, 5)
    black = show_all(np.zeros((hc, wc), np.float32))
    measured = transport_from_captures((show_all(grid.pattern(k)) for k in range(len(grid))), black, grid=grid,
                                 homography=h_cc, radius=2)
    expected = sum(truth.transport(s) @ warps[s] * float(np.mean(1 - truth.projector(s).black)) for s in full.slots)
    err = transport_error(measured, sp.csr_matrix(expected))
    assert err < 0.005, err
