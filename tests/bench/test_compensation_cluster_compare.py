"""bench compensation_cluster compares a run's video with the reference one frame at a time (a whole video
in memory was tens of GB at ``--frames 100000``): identical bytes, the largest code difference and the share
of differing samples, another frame size, another frame count."""
from __future__ import annotations

from bench.compensation_cluster import _compare, _video
from coordinator.assets import AssetStore


def test_videos_are_compared_frame_by_frame(tmp_path):
    (tmp_path / "rig").mkdir()
    store = AssetStore(tmp_path / "rig")
    for name, frames, size in (("a", 6, (64, 32)), ("a again", 6, (64, 32)), ("b", 6, (80, 32)), ("c", 4, (64, 32))):
        _video(tmp_path / f"{name}.mp4", frames, size)
        store.add(tmp_path / f"{name}.mp4", name=name, note=lambda _: None)
    assert _compare(store, "a again", "a") == {"identical_bytes": True, "max_code_diff": 0, "differing_samples": 0.0}
    assert _compare(store, "b", "a") == {"identical_bytes": False, "shapes": [[32, 80, 3], [32, 64, 3]]}
    assert _compare(store, "c", "a") == {"identical_bytes": False, "frames": [4, 6]}
