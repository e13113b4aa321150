"""Blend maps end to end: a coordinator (in this process) and two real node processes on loopback,
each rendering offscreen and writing what it shows as a snapshot. A slot's maps go out in its
assignment; what the nodes show is compared pixel by pixel with the numpy reference
(:func:`protos.spaces.warp_content` with ``blend=``), and what their heartbeats say is read from
the coordinator's node sessions.

* maps at once change that node's picture, and only that node's;
* maps for both nodes at one future instant are shown from exactly that instant (a still on
  screen is shown again with them then: both heartbeats say the same instant), not before;
* maps that cannot be used are refused by the node in one log line, and nothing on its
  projector changes.
"""
from __future__ import annotations

import asyncio
import json
import numpy as np

from coordinator.rig import Content, HomographyPose, Rig
from coordinator.wire import node_messages
from node.image_files import decode_png, decode_png_text
from protos.blend import BlendMaps
from protos.spaces import warp_content
from shadowless.local import LocalRig
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

SLOTS = ["r0c0", "r0c1"]
W, H = 64, 48
RNG = np.random.default_rng(37)


def random_maps() -> BlendMaps:
    return BlendMaps(RNG.random((6, 8, 3), dtype=np.float32), RNG.random((6, 8), dtype=np.float32) * 0.2)


def expected(content: np.ndarray, maps: BlendMaps | None) -> np.ndarray:
    return warp_content(content, np.eye(3), (W, H), blend=None if maps is None else (maps.alpha, maps.beta))


def set_blend(coord, slot: str, maps: BlendMaps | None, at_ns: int) -> None:
    """Change a slot's blend as any slot field changes: a new revision, pushed to its node."""
    coord.update_slot(slot, blend=maps, blend_at_ns=at_ns)


def snapshot(rig: LocalRig, slot: str) -> tuple[np.ndarray | None, dict]:
    """The slot's snapshot and its metadata, as one: the node writes the picture and its metadata as
    two files, so the picture's own ``tEXt`` chunks (written with its pixels) must name the frame and
    swap the metadata names; a read between the two writes counts as no snapshot yet."""
    try:
        meta = json.loads((rig.snapshot_dir / f"{slot}.json").read_text())
        data = (rig.snapshot_dir / f"{slot}.png").read_bytes()
        text = decode_png_text(data)
        if any(text.get(k) != str(meta.get(k)) for k in ("frame_id", "swap_rig_ns")):
            return None, {}
        return decode_png(data), meta
    except (OSError, ValueError):
        return None, {}


def near(image: np.ndarray | None, want: np.ndarray) -> bool:
    """The picture is the reference's: at most 1 level apart, on at most 1 % of the values."""
    if image is None or image.shape != want.shape:
        return False
    diff = np.abs(image.astype(int) - want.astype(int))
    return diff.max() <= 1 and (diff > 0).mean() <= 0.01


async def pictures(rig: LocalRig, want: dict[str, np.ndarray], what: str) -> dict[str, dict]:
    """Wait until every slot of ``want`` shows its picture; their snapshots' metadata."""
    def state():
        return {s: snapshot(rig, s) for s in want}

    got = await wait_until_async(state, lambda st: all(near(st[s][0], want[s]) for s in want), what=what)
    return {s: meta for s, (_, meta) in got.items()}


def test_nodes_show_their_maps_from_their_instant_and_refuse_bad_ones(tmp_path, monkeypatch):
    rig = LocalRig(SLOTS, tmp_path, output_size=(W, H), content_size=(W, H), mdns=False, snapshots=True).create()
    y, x = np.mgrid[0:H, 0:W]
    content = np.stack([x / (W - 1), y / (H - 1), 0.3 + 0.4 * (x + y) / (W + H)], axis=2).astype(np.float32)

    async def go():
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token, listen=f"127.0.0.1:{rig.port}") as app:
            coord = app.coordinator
            try:
                for s in SLOTS:
                    coord.update_slot(s, pose=HomographyPose(np.eye(3)))
                    rig.start_node(s)
                async with await rig.client() as c:
                    await rig.wait_live(c, timeout=120)
                coord.show(Content(content))
                plain = expected(content, None)
                await pictures(rig, {s: plain for s in SLOTS}, "both nodes showing the still, unblended")

                # maps at once, for one node only
                first = random_maps()
                set_blend(coord, "r0c0", first, 0)
                await pictures(rig, {"r0c0": expected(content, first), "r0c1": plain}, "r0c0 blended, r0c1 not")
                assert not near(expected(content, first), plain), "the maps change the picture"
                sess = coord.by_slot["r0c0"]
                await wait_until_async(lambda: sess.blend_id, lambda b: b == first.blend_id,
                                       what="r0c0's heartbeat naming its blend")
                assert sess.blend_since_rig_ns > 0 and coord.by_slot["r0c1"].blend_id == ""

                # maps for both at one instant ahead: not before it, from it on, both at that instant
                new = {s: random_maps() for s in SLOTS}
                at = coord.rig_now() + 3_000_000_000
                for s in SLOTS:
                    set_blend(coord, s, new[s], at)
                revisions = {s: coord.rig.slots[s].revision for s in SLOTS}
                heard = await wait_until_async(
                    lambda: {s: (coord.by_slot[s].heartbeat.assignment_revision, coord.rig_now()) for s in SLOTS},
                    lambda h: all(h[s][0] == revisions[s] for s in SLOTS), what="both nodes holding the new maps")
                if max(now for _, now in heard.values()) < at:     # the machine kept up: before the instant
                    assert near(snapshot(rig, "r0c0")[0], expected(content, first))
                    assert near(snapshot(rig, "r0c1")[0], plain)
                    assert coord.by_slot["r0c0"].blend_id == first.blend_id and coord.by_slot["r0c1"].blend_id == ""
                metas = await pictures(rig, {s: expected(content, new[s]) for s in SLOTS}, "both nodes on the new maps")
                assert all(m["swap_rig_ns"] >= at - 2_000_000 for m in metas.values()), \
                    ({s: (m.get("swap_rig_ns"), m.get("frame_id")) for s, m in metas.items()}, at,
                     {s: [ln for ln in rig.log(f"node-{s}").splitlines() if "blend" in ln][-6:]
                      for s in SLOTS})
                since = await wait_until_async(
                    lambda: {s: (coord.by_slot[s].blend_id, coord.by_slot[s].blend_since_rig_ns) for s in SLOTS},
                    lambda b: all(b[s][0] == new[s].blend_id for s in SLOTS), what="both heartbeats naming the new maps")
                assert {s: t for s, (_, t) in since.items()} == {s: at for s in SLOTS}, "one common swap instant"

                # maps that cannot be used: one line in the node's log, nothing changes on its projector
                def spoiled(maps, *, at_ns=0):
                    msg = node_messages.node_pb2.Blend()
                    msg.CopyFrom(real(maps, at_ns=at_ns))
                    msg.beta = np.full(msg.width * msg.height, np.nan, "<f2").tobytes()
                    return msg

                real = node_messages.blend_message
                monkeypatch.setattr(node_messages, "blend_message", spoiled)
                set_blend(coord, "r0c1", random_maps(), 0)
                revision = coord.rig.slots["r0c1"].revision
                await wait_until_async(lambda: coord.by_slot["r0c1"].heartbeat.assignment_revision,
                                       lambda r: r == revision, what="r0c1 holding the spoiled assignment")
                text = await wait_until_async(lambda: rig.log("node-r0c1"), lambda t: "blend maps refused" in t,
                                              what="r0c1's refusal")
                refusals = [line for line in text.splitlines() if "blend maps refused" in line]
                assert len(refusals) == 1 and "NaN" in refusals[0], refusals
                assert near(snapshot(rig, "r0c1")[0], expected(content, new["r0c1"]))
                assert coord.by_slot["r0c1"].blend_id == new["r0c1"].blend_id
            finally:
                rig.close()

    asyncio.run(go())
