"""The bust bench's oracle (:func:`bench.compensation_bust_oracle.bust_oracle`) on one projector, where the
per-projector baseline's problem is ours (its share of the target is all of it): with the true transport both
must come out the same texture, scored alike, and compensation must beat none through the true transport."""
from __future__ import annotations

import asyncio

import pytest

from bench.compensation_bust import bust_room, make_bust_rig, truth_mesh_transport
from bench.compensation_bust_oracle import bust_oracle
from shadowless.room_driver import RoomDriver

CONTENT = (128, 96)
SLOTS = ["r2c2"]


def test_one_projector_the_baseline_is_ours_and_both_beat_none(tmp_path):
    room = bust_room(projector_scale=0.25, camera_scale=0.125, seed=2)
    rig = make_bust_rig(tmp_path / "rig", room, SLOTS, content_size=CONTENT, luts=True)
    out = asyncio.run(RoomDriver(room, rig).run("transport", {"settle_s": 0.0, "baseline": True,
                                                              "baseline_exposure": 1.0}))
    assert out["baseline"]["captures"] > 0                       # L and the one L_i, measured apart
    job = {"solve": {"regularization": 0.02, "method": "apg"}, "target_level": 0.9}
    oracle = bust_oracle(lambda which: truth_mesh_transport(room, rig, which), rig, SLOTS, job, max_iter=30)
    true, measured = oracle["true_transport"], oracle["measured_transport"]
    assert true["ours"] == true["baseline"] and true["ours_minus_baseline_db"] == 0.0
    for scores in (true, measured):
        assert scores["ours"]["psnr"] > scores["none"]["psnr"] + 0.2, scores
        assert scores["ours"]["pixels"] == scores["none"]["pixels"] > 100
    # L and L_i are two measurements of the same light: what they make of it differs by their noise only
    assert measured["ours_minus_baseline_db"] == pytest.approx(0.0, abs=0.3)
