"""Crossfades in the presenter, on a real renderer (EGL, llvmpipe) and an offscreen output, on a
clock the test moves (the harness of test_presenter.py): a still's fade is shown step by step at
the rig instants protos/fade.py gives, each step reported as a frame of its own and mixed as numpy
mixes it; a fade whose first step comes too late goes on from its later steps and ends on the new
picture; a timeline show with a fade mixes its first ticks with the still that was on screen."""
from __future__ import annotations

import importlib.util
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from node.records import NodeAssignment, ShowUpdateData
from protos.fade import step_mix, step_pts
from protos.spaces import quantise
from protos.timeline import Timeline

_spec = importlib.util.spec_from_file_location("presenter_harness", Path(__file__).with_name("test_presenter.py"))
harness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(harness)
MS, W, H = harness.MS, harness.W, harness.H


def level(before: int, after: float, m: float) -> int:
    """The node's output level for a mix of two flat pictures (``after`` linear 0..1)."""
    return int(quantise(np.array([(before / 255) * (1 - m) + after * m]))[0])


@pytest.fixture
def rig():
    r = harness.Rig()
    p = r.presenter
    p.open()
    p.handle("assignment", NodeAssignment(
        revision=1, slot="r0c0", width=W, height=H, pose_kind="homography", homography=np.eye(3), projection=None,
        mesh=None, near_mm=100.0, far_mm=10_000.0, lut=None, gain=1.0, content_size=(W, H)))
    p.handle("clock", harness.estimate())
    for value in (40, 200):
        p.handle("content", (f"c{value}", harness.still(value)))
    r.reports.clear()
    yield r
    p.close()


def content_frame(rig, frame_id: int, in_ms: float, cid: str, **fade):
    return replace(rig.frame(frame_id, in_ms=in_ms, content=cid), space="content", apply_lut=True, **fade)


def test_a_still_fades_step_by_step_and_a_late_first_step_lets_it_go_on(rig):
    p = rig.presenter
    rig.show(content_frame(rig, 100, 20, "c40"))
    first = content_frame(rig, 200, 20, "c200", fade_ns=300 * MS, fade_steps=3)
    rig.show(first)
    for k in range(1, 4):
        assert p.timeline_wait() is not None
        p.timeline_step()
        assert rig.swaps[-1].frame_id == 200 + k
        assert rig.swaps[-1].swap_rig_ns >= step_pts(first.pts_ns, first.fade_ns, k, 3)
        want = level(40, 200 / 255, step_mix(k, 3))
        assert int(p.renderer.read()[0, 0, 0]) == want, (k, want)
    assert p.timeline_wait() is None and int(p.renderer.read().max()) == 200

    # a fade into c40 whose first step is already past: dropped as late, the later steps are shown
    late = content_frame(rig, 300, -50, "c40", fade_ns=300 * MS, fade_steps=3)
    rig.show(late)
    assert rig.drops[-1].frame_id == 300
    while p.timeline_wait() is not None:
        p.timeline_step()
    assert rig.swaps[-1].frame_id == 303 and int(p.renderer.read().max()) == 40


def test_a_show_fades_in_from_the_still_on_screen(rig, tmp_path):
    p = rig.presenter
    rig.show(content_frame(rig, 100, 20, "c200"))
    files = harness._still_asset(tmp_path)          # flat 0.5 grey, played at 10 fps
    anchor = rig.rig_now() + 20 * MS
    tl = Timeline(asset_id=files.asset_id, frames=1, rate=Fraction(10), anchor_ns=anchor, loop=True, revision=1,
                  fade_ns=400 * MS)
    p.handle("asset", files)
    p.handle("show", ShowUpdateData(timeline=tl, frame_id_base=500))
    harness.first_frame_decoded(p)
    seen = []
    for k in range(6):
        p.timeline_step()
        seen.append(int(p.renderer.read()[0, 0, 0]))
    assert [s.frame_id for s in rig.swaps[-6:]] == list(range(500, 506))
    assert seen == [level(200, 0.5, min(1.0, k / 4)) for k in range(6)], seen
