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


def test_a_steep_reach_is_the_finger_and_a_shallow_one_is_tilted_into_the_surface():
    from sim.touch import MIN_INTO_DEG, reach_direction

    X = np.array([0.0, 100.0, 200.0])
    n = np.array([0.0, 1.0, 0.0])
    steep = np.array([0.0, 600.0, 650.0])                  # 48 degrees into the surface: kept
    r = (X - steep) / np.linalg.norm(X - steep)
    np.testing.assert_allclose(reach_direction(X, n, steep), r, atol=1e-12)
    top = np.array([0.0, 0.0, 1.0])                         # the top of a head, the shoulder 50 mm above it
    shallow = np.array([0.0, 600.0, 250.0])
    g = reach_direction(X, top, shallow)
    a = np.radians(MIN_INTO_DEG)                           # closed form: the reach's level part, tilted down
    np.testing.assert_allclose(g, [0.0, -np.cos(a), -np.sin(a)], atol=1e-12)
    np.testing.assert_allclose(reach_direction(X, n, X + 500 * n), -n, atol=1e-12)   # straight along the normal


def test_a_reaching_hand_joins_its_elbow_to_the_shoulder_and_touches_the_point():
    from sim.touch import UPPER_ARM_RADIUS, reach_direction

    X = np.array([40.0, 120.0, 250.0])
    n = np.array([0.2, 1.0, 0.3])
    shoulder = np.array([100.0, 650.0, 650.0])
    hand = TouchingHand.reaching(X, n, shoulder)
    plain = TouchingHand(X, n, direction=reach_direction(X, n, shoulder), towards=(0, 0, 1))
    arm = hand.primitives()[-1]
    assert len(hand.primitives()) == len(plain.primitives()) + 1
    np.testing.assert_allclose(arm.b, shoulder)
    assert arm.radius == pytest.approx(UPPER_ARM_RADIUS)
    forearm = max((q for q in plain.primitives() if isinstance(q, Capsule)), key=lambda q: q.radius)
    np.testing.assert_allclose(arm.a, forearm.b, atol=1e-9)            # from the elbow
    for q, p in zip(hand.primitives(), plain.primitives()):             # the rest is the plain hand
        np.testing.assert_allclose(getattr(q, "a", getattr(q, "center", None)), getattr(p, "a", getattr(p, "center", None)))
    nu = n / np.linalg.norm(n)
    t, _ = cast_rays(X[None], nu[None], hand.primitives())
    assert t[0] == pytest.approx(0.5, abs=1e-6)                         # the fingertip 0.5 mm off the point
    assert inside(hand, shoulder[None] + [0.0, 0.0, -30.0])[0]         # the arm reaches the shoulder
    with pytest.raises(ValueError, match="shoulder"):
        TouchingHand(X, n, shoulder=(0.0, np.nan, 0.0))
