"""A hand touching a point in 3D: where its fingertip sits, where it points, and the shadow it casts."""
from __future__ import annotations

import numpy as np
import pytest

from sim.occluders import Capsule, cast_rays
from sim.touch import TouchingHand, inside


def index_finger(hand: TouchingHand) -> Capsule:
    centre, _ = hand.fingertip
    return next(q for q in hand.primitives() if isinstance(q, Capsule) and np.allclose(q.b, centre))


@pytest.mark.parametrize("normal", [(0, 0, 1), (0, 1, 0.1), (-0.9, -0.3, -0.3), (0.5, -0.5, 0.7)])
def test_the_fingertip_touches_the_point_and_the_finger_points_inwards(normal):
    X = np.array([30.0, -20.0, 400.0])
    hand = TouchingHand(X, normal, gap=0.5)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    centre, r = hand.fingertip
    np.testing.assert_allclose(centre, X + (r + 0.5) * n, atol=1e-9)
    f = index_finger(hand)
    axis = (f.b - f.a) / np.linalg.norm(f.b - f.a)
    np.testing.assert_allclose(axis, -n, atol=1e-9)
    # the ray out of the surface along the normal meets the hand after exactly the gap (exact ray tests)
    t, _ = cast_rays(X[None], n[None], hand.primitives())
    assert t[0] == pytest.approx(0.5, abs=1e-6)
    assert not inside(hand, X[None])[0] and inside(hand, centre[None])[0]
    # the rigid move keeps the hand's shape: the finger is as long and thick as the table hand's
    assert f.radius == pytest.approx(8.5) and np.linalg.norm(f.b - f.a) == pytest.approx(70.0)


def test_the_forearm_leans_where_it_is_told_and_the_finger_may_tilt():
    X = np.zeros(3)
    n = np.array([0.0, 1.0, 0.0])
    for towards in ((0, 0, 1), (1, 0, 0)):
        hand = TouchingHand(X, n, towards=towards)
        forearm = max((q for q in hand.primitives() if isinstance(q, Capsule)), key=lambda q: q.radius)
        lean = forearm.b - forearm.a
        assert lean @ np.asarray(towards, float) > 0.3 * np.linalg.norm(lean)
        assert lean @ n > 0                          # away from the surface
    d = np.array([0.0, -1.0, -1.0]) / np.sqrt(2)
    tilted = TouchingHand(X, n, direction=d)
    f = index_finger(tilted)
    np.testing.assert_allclose((f.b - f.a) / np.linalg.norm(f.b - f.a), d, atol=1e-9)
    with pytest.raises(ValueError, match="into the surface"):
        TouchingHand(X, n, direction=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError):
        TouchingHand(X, (0, 0, 0))


def test_a_touch_on_the_table_darkens_the_contact_and_nothing_far_away():
    """25 projectors at most 27 degrees off vertical; the fingertip sphere hides the point below it
    from every direction within 70 degrees: the contact loses all its light, the far table none."""
    from sim.room import Room
    from sim.scene import reference_scene

    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), noise=False)
    X = np.array([100.0, 50.0, 0.0])
    room.set_occluders([TouchingHand(X, (0, 0, 1), gap=0.5)])
    drop = room.truth.light_drop()
    surf = room.truth.surface()
    d = np.linalg.norm(surf.points[..., :2] - X[:2], axis=-1)
    assert np.nanmin(d) < 3
    contact = np.unravel_index(np.nanargmin(d), d.shape)
    assert drop[contact] > 0.95
    assert drop[d > 400].max() < 0.1 and (drop[d > 400] == 0).mean() > 0.9
    assert room.truth.occluder_mask().any()          # the camera sees the hand
