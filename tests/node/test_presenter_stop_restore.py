"""Stop during a played show: the coordinator stops the show's timeline (on the Show stream) and
shows the rig's content again (a still, on the Frames stream). The two streams race; when the
still arrives and is swapped in first, the stop that follows must not black the projector out
(it did, and the console's thumbnails turned black while the room's camera, which hears only of
swaps, still showed the picture).

As in test_presenter.py: a real renderer (EGL, llvmpipe) and an offscreen output, on a clock the
test moves.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from node.image_files import decode_png
from node.records import ShowUpdateData

_spec = importlib.util.spec_from_file_location("presenter_harness", Path(__file__).with_name("test_presenter.py"))
harness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(harness)
MS = harness.MS


def test_a_stop_arriving_after_the_restored_still_leaves_the_still_on_screen(tmp_path):
    rig = harness.Rig()
    p = rig.presenter
    p.open()
    try:
        p.handle("assignment", harness.assignment())
        p.handle("clock", harness.estimate())
        p.handle("content", ("c200", harness.still(200)))
        files = harness._still_asset(tmp_path)
        anchor = rig.rig_now() + 10 * MS
        p.handle("asset", files)
        p.handle("show", harness._timeline_update(files, anchor))
        harness.first_frame_decoded(p)
        p.timeline_step()                                   # the show's first tick is on screen
        stop_at = rig.rig_now()                             # the coordinator stops the show now ...
        still = rig.frame(10_000, in_ms=30, content="c200")  # ... and restores its content a moment later
        rig.show(still)                                     # the still arrives first and is swapped in
        swaps = rig.out.swaps
        p.handle("show", ShowUpdateData(stop_at_ns=stop_at, stop_revision=2))
        p.timeline_step()                                   # the stop, already due
        assert rig.out.swaps == swaps, "the stop swapped black in over the restored still"
        assert p.timeline_wait() is None
        np.testing.assert_array_equal(p.renderer.read(), harness.still(200))
        # the console's thumbnail: the still, under its own frame id
        p.handle("preview", 1)
        previews = [r for k, r in rig.reports if k == "preview"]
        assert previews and previews[-1].frame_id == 10_000
        assert int(decode_png(previews[-1].png).min()) == 200
    finally:
        p.close()
