"""Cues end to end: a coordinator (in this process) and two real node processes on loopback, each
rendering offscreen and writing what it shows as a snapshot. GO, back, jump and auto-follow change
the pictures on both projectors; a crossfade's steps are mixed by the nodes' shaders (a snapshot
taken mid-fade is the numpy mix of the two pictures at its step's factor, on both nodes, for the
same step ids); the current cue survives a coordinator restart; every fire is handed to the
action log with who fired it (the command line's GO is its own entry, not the engine's)."""
from __future__ import annotations

import asyncio
import contextlib
import json
from pathlib import Path

import numpy as np

from coordinator.assets import AssetStore
from coordinator.rig import Content, HomographyPose, Rig
from node.image_files import decode_png, decode_png_text, write_png
from protos.cues import Cue, CueList
from protos.fade import mix_reference, step_mix
from protos.spaces import as_linear, warp_content
from shadowless.local import LocalRig
from cli_inprocess import run_shadowless
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

SLOTS = ["r0c0", "r0c1"]
W, H = 64, 48


def snapshot(rig: LocalRig, slot: str) -> tuple[np.ndarray | None, dict]:
    """The slot's snapshot and its metadata, as one (see tests/node/test_node_blend.py)."""
    try:
        meta = json.loads((rig.snapshot_dir / f"{slot}.json").read_text())
        data = (rig.snapshot_dir / f"{slot}.png").read_bytes()
        text = decode_png_text(data)
        if any(text.get(k) != str(meta.get(k)) for k in ("frame_id", "swap_rig_ns")):
            return None, {}
        return decode_png(data), meta
    except (OSError, ValueError):
        return None, {}


def near(image: np.ndarray | None, want: np.ndarray, share: float = 0.01) -> bool:
    """At most 1 level apart, on at most ``share`` of the values. A mix of two 8-bit pictures at k / K
    lands on many exact halves, which float32 on the GPU and float64 here may round apart: 5 % then."""
    if image is None or image.shape != want.shape:
        return False
    diff = np.abs(image.astype(int) - want.astype(int))
    return diff.max() <= 1 and (diff > 0).mean() <= share


def shown(content: np.ndarray) -> np.ndarray:
    return warp_content(content, np.eye(3), (W, H))


async def pictures(rig: LocalRig, want: np.ndarray, what: str) -> dict[str, dict]:
    got = await wait_until_async(lambda: {s: snapshot(rig, s) for s in SLOTS},
                                 lambda st: all(near(st[s][0], want) for s in SLOTS), what=what)
    return {s: meta for s, (_, meta) in got.items()}


def test_go_back_jump_follow_and_crossfades_on_real_nodes(tmp_path, capfd):
    rig = LocalRig(SLOTS, tmp_path, output_size=(W, H), content_size=(W, H), mdns=False, snapshots=True).create()
    y, x = np.mgrid[0:H, 0:W]
    first = np.stack([x * 255 // (W - 1), y * 255 // (H - 1), np.full_like(x, 60)], axis=2).astype(np.uint8)
    second = np.stack([255 - x * 255 // (W - 1), np.full_like(x, 200), (x + y) * 255 // (W + H)],
                      axis=2).astype(np.uint8)
    write_png(tmp_path / "second.png", second)
    AssetStore(rig.rig_dir).add(tmp_path / "second.png", name="second")
    black = np.zeros((H, W, 3), np.uint8)
    fires: list[dict] = []

    @contextlib.asynccontextmanager
    async def served():
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token, listen=f"127.0.0.1:{rig.port}") as app:
            app.coordinator.cue_engine().on_fire = lambda **entry: fires.append(entry)
            yield app

    async def go():
        async with served() as app:
            coord = app.coordinator
            for s in SLOTS:
                coord.update_slot(s, pose=HomographyPose(np.eye(3)))
                rig.start_node(s)
            async with await rig.client() as c:
                await rig.wait_live(c, timeout=120)
            coord.show(Content(first), persist=True)
            await pictures(rig, shown(first), "both nodes showing the rig's content")
            coord.set_cues(CueList((Cue("1", "Black", "blackout"),
                                    Cue("2", "In", "still", "content", fade_s=0.6),
                                    Cue("3", "Cross", "asset", "second", fade_s=2.0),
                                    Cue("4", "Out", "blackout", follow_s=0.5),
                                    Cue("5", "Again", "still", "second"))), who="ana")

            coord.cue_go(who="ana")                                       # 1: black, a cut
            await pictures(rig, black, "cue 1: black on both")
            coord.cue_go(who="ana")                                       # 2: from black, faded in
            await pictures(rig, shown(first), "cue 2: the content faded in")

            # 3: a 2 s crossfade into a still asset; a snapshot mid-fade is the shader's mix at its step
            coord.cue_go(who="bo")
            frame = await wait_until_async(lambda: coord.playback.current_frame, lambda f: f.tag == "show:cue:3",
                                           what="cue 3's frame sent")
            assert frame.fade_steps > 2 and coord.cue_state().fading
            base, steps = frame.frame_id, frame.fade_steps

            def mid(st):
                ids = {s: st[s][1].get("frame_id", 0) - base for s in SLOTS}
                return {s: k for s, k in ids.items() if 0 < k < steps and near(
                    st[s][0], shown(mix_reference(as_linear(first), as_linear(second), step_mix(k, steps))), 0.05)}

            seen: dict[str, int] = {}
            await wait_until_async(lambda: {s: snapshot(rig, s) for s in SLOTS},
                                   lambda st: seen.update(mid(st)) or len(seen) == len(SLOTS),
                                   what="each node showing a step of the crossfade, mixed as numpy mixes it",
                                   interval=0.01)
            metas = await pictures(rig, shown(second), "cue 3: the asset after the fade")
            assert {m["frame_id"] for m in metas.values()} == {base + steps}, "both end on the fade's last step"
            assert metas[SLOTS[0]]["pts_ns"] == metas[SLOTS[1]]["pts_ns"], "the same step at the same instant"

            coord.cue_back(who="bo")                                      # back to 2: a cut
            await pictures(rig, shown(first), "back: cue 2's content")
            coord.cue_jump("4", who="cy")                                 # 4: black, then follows into 5
            await wait_until_async(lambda: coord.cue_state().current, lambda c: c == 4,
                                   what="cue 5 fired by cue 4's auto-follow")
            await pictures(rig, shown(second), "cue 5 after the follow")
            await wait_until_async(lambda: len(fires), lambda n: n >= 6, what="six fires in the action log")
            assert [(f["who"], f["params"]["cue"]) for f in fires] == [
                ("ana", "1"), ("ana", "2"), ("bo", "3"), ("bo", "2"), ("cy", "4"), ("follow", "5")]
            assert all(f["ok"] and f["action"] == "cue fire" for f in fires)

            # a follow is cancelled by anything else taking the projectors
            coord.cue_jump("4", who="cy")
            await pictures(rig, black, "cue 4 again")
            coord.stop_all()
            engine = coord.cue_engine()
            await wait_until_async(lambda: engine._follow, lambda t: t is None or t.done(),
                                   what="the follow's instant passing", timeout=60)
            assert coord.cue_state().current == 3, "the follow did not fire over the operator's stop"

        # a restarted coordinator shows the current cue (4, black) again; the command line drives it
        async with served() as app:
            assert app.coordinator.cue_state().current == 3
            await pictures(rig, black, "cue 4 on screen again after the restart")
            where = ["--coordinator", f"127.0.0.1:{rig.port}", "--rig-dir", rig.rig_dir]

            async def cli(*argv):
                return await asyncio.to_thread(run_shadowless, ["cue", *argv, *where], capfd)

            code, out, err = await cli("list")
            assert code == 0, err
            marked = [ln.split()[:2] for ln in out.splitlines() if ln.startswith(("▶", "→"))]
            assert marked == [["▶", "4"], ["→", "5"]], out
            assert "5 cues; current: cue 4" in out
            code, out, err = await cli("add", "--kind", "still")
            assert (code, err.strip()) == (
                2, "shadowless cue add: cue '6': a still cue needs a target (a still's name, e.g. content)"), err
            code, out, err = await cli("add", "--kind", "still", "--target", "content", "--at", "1", "--name", "Top")
            assert code == 0 and "added cue 6 'Top' (still content) at position 1" in out, err
            assert [c.id for c in app.coordinator.cue_state().cues] == ["6", "1", "2", "3", "4", "5"]
            code, out, err = await cli("jump", "9")
            assert code == 2 and err.startswith("shadowless cue jump: ") and "no cue '9' in the list" in err, err
            code, out, err = await cli("jump", "6")
            assert code == 0 and out.startswith("cue 6 'Top' (still content) fires; next: 1"), out + err
            await pictures(rig, shown(first), "cue 6 fired from the command line")
            assert all(f["params"]["cue"] != "6" for f in fires), "the command line's jump is its own entry"
            last = json.loads((Path(rig.rig_dir) / "console-actions.jsonl").read_text().splitlines()[-1])
            assert (last["who"], last["address"], last["action"], last["params"]) == (
                "token", "127.0.0.1", "cli cue jump", {"id": "6"}), last

    try:
        asyncio.run(go())
    finally:
        rig.close()
