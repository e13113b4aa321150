"""The hand: its placement on the table, its yaw and sides, and hand paths."""
from __future__ import annotations

import numpy as np
import pytest

from sim.hand import Hand, HandPath
from sim.occluders import segment_blocked


@pytest.mark.parametrize("pose", ["flat", "point"])
@pytest.mark.parametrize("height", [0.0, 200.0])
def test_hand_sits_at_its_height_and_position(pose, height):
    hand = Hand(position=(120.0, -40.0), height=height, pose=pose, yaw_deg=30.0)
    assert hand.lowest_z() == pytest.approx(height, abs=1e-9)
    prims = hand.primitives()
    if pose == "flat":
        palm = prims[0]
        np.testing.assert_allclose(palm.center[:2], [120.0, -40.0], atol=1e-9)
    else:
        index_tip = prims[1].b  # the index finger's far end
        np.testing.assert_allclose(index_tip[:2], [120.0, -40.0], atol=1e-9)
        assert index_tip[2] - prims[1].radius == pytest.approx(height, abs=1e-9)
    c, r = Hand(height=height, pose=pose).primitives()[0].bounding_sphere()
    assert r < 60


def test_hand_yaw_and_sides():
    up = Hand(yaw_deg=0.0)
    fingers_y = up.primitives()[2].b[1] - up.primitives()[0].center[1]
    assert fingers_y > 100  # the middle finger points along +y
    turned = Hand(yaw_deg=90.0)
    assert turned.primitives()[2].b[0] - turned.primitives()[0].center[0] < -100  # +y rotated to -x
    right_thumb = Hand(side="right").primitives()[5]
    left_thumb = Hand(side="left").primitives()[5]
    assert right_thumb.b[0] < 0 < left_thumb.b[0]
    with pytest.raises(ValueError):
        Hand(pose="fist")


def test_hand_path_interpolates_and_loops():
    path = HandPath.sweep((-300.0, 0.0), (300.0, 0.0), height=150.0, period=4.0)
    assert path.hand_at(0.0).position == pytest.approx((-300.0, 0.0))
    assert path.hand_at(1.0).position == pytest.approx((0.0, 0.0))
    assert path.hand_at(2.0).position == pytest.approx((300.0, 0.0))
    assert path.hand_at(5.0).position == pytest.approx((0.0, 0.0))
    assert path.hand_at(1.0).height == 150.0
    once = HandPath(((0.0, 0.0, 0.0, 100.0), (1.0, 10.0, 0.0, 50.0)), loop=False)
    assert once.hand_at(3.0).position == (10.0, 0.0) and once.hand_at(0.5).height == pytest.approx(75.0)
    with pytest.raises(ValueError):
        HandPath(((1.0, 0, 0, 0), (0.5, 0, 0, 0)))


def test_a_hand_shadows_what_lies_under_it_and_not_beside_it():
    """The hand is an occluder like any solid: a segment from the table up through the palm is
    blocked, one from a point far beside the hand is not."""
    hand = Hand(position=(0.0, 0.0), height=150.0)
    up = np.array([[0.0, 0.0, 0.0], [400.0, 0.0, 0.0]])
    tops = up + np.array([0.0, 0.0, 2000.0])
    blocked = segment_blocked(up, tops, hand.primitives())
    assert blocked.tolist() == [True, False]
