"""Renderer.forget: content forgotten for reuse lends its texture to the next upload of its size;
content forgotten with reuse=False is released, and the next upload of its size draws its own picture."""
from __future__ import annotations

import numpy as np
import pytest

from node.render import Renderer
from protos.yuv import YuvFrame

W, H = 48, 32


@pytest.fixture(scope="module")
def renderer():
    r = Renderer.standalone(W, H)
    yield r
    r.release()


def _yuv(level: int) -> YuvFrame:
    return YuvFrame(planes=(np.full((H, W), level, np.uint8), np.full((H // 2, W // 2), 128, np.uint8),
                            np.full((H // 2, W // 2), 128, np.uint8)), layout="planar", full_range=True)


@pytest.mark.parametrize("reuse", [True, False])
def test_each_upload_after_forget_draws_its_own_picture(renderer, reuse):
    for k, level in enumerate((40, 200, 90)):
        rgb = np.full((H, W, 3), level, np.uint8)
        renderer.upload(f"rgb{k}", rgb)
        renderer.render(f"rgb{k}", space="projector", apply_lut=False)
        assert np.array_equal(renderer.read(), rgb)
        renderer.forget(f"rgb{k}", reuse=reuse)
        assert not renderer.has(f"rgb{k}")
    renderer.set_homography(np.eye(3), (W, H))
    for k, level in enumerate((30, 220)):
        renderer.upload(f"yuv{k}", _yuv(level))
        renderer.render(f"yuv{k}", apply_lut=False)
        assert np.abs(renderer.read().astype(int) - level).max() <= 1
        renderer.forget(f"yuv{k}", reuse=reuse)
    renderer.clear_pose()
