"""protos.spaces.output_outline: a projector's output rectangle in content pixels, checked against
OpenCV's perspectiveTransform of the corners through the inverse pose."""
from __future__ import annotations

import cv2
import numpy as np

from protos.spaces import output_outline


def test_the_outline_is_the_inverse_pose_of_the_output_corners():
    src = np.float32([[0, 0], [159, 0], [159, 89], [0, 89]])
    dst = np.float32([[10, 8], [300, 2], [310, 170], [4, 176]])
    pose = cv2.getPerspectiveTransform(src, dst).astype(np.float64)      # content px -> projector px
    corners = np.float64([[-0.5, -0.5], [319.5, -0.5], [319.5, 179.5], [-0.5, 179.5]])
    expected = cv2.perspectiveTransform(corners[None], np.linalg.inv(pose))[0]
    got = output_outline(pose, (320, 180), (160, 90))
    assert got.shape == (4, 2) and got.dtype == np.float64
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(output_outline(-pose, (320, 180), (160, 90)), expected, rtol=0, atol=1e-9), \
        "a pose is defined up to sign"


def test_no_outline_for_a_singular_pose_or_a_corner_beyond_the_horizon():
    assert output_outline(np.zeros((3, 3)), (320, 180), (160, 90)) is None
    # the inverse sends the right half of the output behind the viewer (its w changes sign)
    beyond = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.01, 0.0, 1.0]])
    assert output_outline(beyond, (320, 180), (160, 90)) is None
