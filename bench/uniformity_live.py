"""`bench uniformity`'s live parts: failover and the photometric watchdog with real processes.

The room runs as a process of its own (``shadowless room``, the same room as the in-process
parts' with ``--no-signal black``: a projector whose node died goes dark), one node process per
projector sends it what it shows, and the coordinator runs in this process
(:class:`coordinator.app.CoordinatorApp`, listening on 127.0.0.1 like ``shadowless coordinator``;
the benchmark's own work runs in worker threads so that its event loop keeps serving), so the benchmark reads what the core knows -- the blend status and each node's
heartbeat (the blend on its screen and the pts of the first frame shown with it) -- without a
status call's rounding. A twin of the room built here gives the truth (footprints). The rig's poses and LUTs are the room's truth (calibration and responses
are measured by the in-process parts and by ``bench compensation_room``); the camera is mapped to
the table by the ``calibrate`` job from clicked marks; the ``blend`` job measures through the room's
camera.

* **Failover**: during a looping flat-white timeline show (a still with ``--show still``, and by
  default on rigs of more than 9 nodes, whose 30 frames a second each two cores cannot carry), one node
  (the centre's) is killed with SIGKILL and its projector goes dark (no signal), once the
  coordinator has computed every single loss's maps ahead (as it has long before a loss in a show). Reported: the time until the coordinator
  declares the loss (``BlendStatus.since``), the non-uniformity in the lost footprint once every
  remaining node shows its new maps,
  how many frame periods (at ``--fps``) after the declaration those maps were on screen (the
  latest of the nodes' first frames with them) and how far apart the nodes switched; the switch lead
  (``[blend] switch_lead_ms``, ``--switch-lead-ms``) and how many nodes heard of the maps too late for
  the common instant (``late_nodes``: they show them from their next frame); then the node is started
  again and the time until the maps switched back. With ``--cpu-budget F`` each rig runs a second
  time with every node process held to ``F`` of a core and its rasterizer's threads (llvmpipe, the
  GPU's stand-in) in a group of their own without a limit (:mod:`shadowless.rig_budget`; under
  ``cpu_budget``), so that starved CPU and the protocol can be told apart. ``stages_ms`` says where
  a failover's time went: the coordinator's stamps (wanted, ready, set, the instant) and each node's
  (received, decoded, read by the presenter, uploaded, the first frame shown with the maps, its swap
  done, the coordinator told), p50 and max over the nodes. ``cpu_ms`` says whose CPU the loss took,
  from the kill until every node was seen showing its maps (:mod:`bench.uniformity_cpu`): the node
  processes, their presenters, the room, this process (the coordinator), the whole host and the rest
  of it (``others``), so that a slow switch can be told to be the rig's work or a shared machine's.
* **Watchdog**: one lamp dimmed to 50 % and another to 0 through the room's lamp switch while
  their nodes stay live; the time until the watchdog names each, its gain estimates against the
  room's truth, and the non-uniformity over both footprints once re-blended. The rig shows a flat
  white still: the watchdog predicts the light of a still (a show would change under its capture).

Non-uniformity is :func:`bench.uniformity_measure.nonuniformity` against what the blend of all
projectors means the camera to see (recomputed from the stored contributions), scored in the
footprint with the scale ``k`` of the capture before the change (same camera, same exposure), so
light lost everywhere at once counts as well as an uneven footprint (``after_own_scale`` fits ``k``
to the capture itself); ``light_kept`` is the footprint's light after over before.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.calibration import table_points_from_truth
from bench.compensation_room import points_doc
from bench.uniformity_cpu import CpuSnapshot, children_of
from bench.uniformity_measure import nonuniformity, scale_of
from bench.uniformity_room import blend_params, stored_target, truth_luts
from bench.uniformity_scenes import Light, Missing, slots_of, table_room
from coordinator.rig import HomographyPose, Rig
from shadowless.local import LocalRig
from shadowless.process_stop import stop_process
from sim.room import Room

__all__ = ["part_failover", "part_watchdog"]


def _log(msg: str) -> None:
    print(f"[bench uniformity] {msg}", file=sys.stderr, flush=True)


@dataclass
class Live:
    """A running rig: the room's process (and its twin here), the node processes, the coordinator in this process."""

    room: Room                         # a twin of the room process, for its truth
    address: str                       # the room process
    local: LocalRig
    app: object
    client: object
    slots: list[str]
    content_size: tuple[int, int]
    exposure: float = 1.0
    shown_pts: int = 0                 # the rig instant the flat white went on screen
    result: dict | None = None         # the blend job's result
    ahead_s: float | None = None       # how long the coordinator took to compute the failover variants ahead
    room_pid: int = 0                  # the room process

    def cpu_snapshot(self, slots) -> CpuSnapshot:
        """The run times of ``slots``' node processes, their presenters, the room and this process (the coordinator)."""
        nodes = [p.pid for s, p in self.local.nodes.items() if s in slots and p.poll() is None]
        return CpuSnapshot({"nodes": nodes, "presenters": [c for p in nodes for c in children_of(p)],
                            "room": [self.room_pid] if self.room_pid else [], "coordinator": [os.getpid()]},
                           threads_of=os.getpid())

    @property
    def core(self):
        return self.app.coordinator

    def blend_status(self):
        fn = getattr(self.core, "blend_status", None)
        if fn is None:
            raise Missing("the coordinator reports no blend status (Coordinator.blend_status, failover) in this build")
        return fn()

    def session(self, slot: str):
        s = self.core.by_slot.get(slot)
        return None if s is None or s.closed else s

    def slot_blend_id(self, slot: str) -> str:
        b = self.core.rig.slot(slot).blend
        return "" if b is None else b.blend_id

    def showing_assigned(self, slots) -> bool:
        """Every one of ``slots`` has a live node whose heartbeat says it shows its slot's current blend."""
        for s in slots:
            sess = self.session(s)
            want = self.slot_blend_id(s)
            if sess is None or not want or getattr(sess, "blend_id", None) != want:
                return False
        return True

    def since_ns(self, slots) -> list[int]:
        return [int(self.session(s).blend_since_rig_ns) for s in slots]

    async def acapture(self, frames: int, *, not_before_ns: int = 0) -> np.ndarray:
        """:meth:`capture` in a worker thread: the coordinator's event loop, in this process, keeps serving."""
        return await asyncio.to_thread(self.capture, frames, not_before_ns=not_before_ns)

    def set_lamp(self, slot: str, gain: float) -> None:
        """The room process's lamp switch: ``slot``'s lamp at ``gain`` while its node stays live."""
        from sim.link import RoomClient
        with RoomClient(self.address) as rc:
            rc.set_lamp(slot, gain)

    def capture(self, frames: int, *, not_before_ns: int = 0) -> np.ndarray:
        """The mean of ``frames`` captures through the room's service, each taken once every active projector
        swapped a frame at or after ``not_before_ns`` (rig clock = this host's monotonic clock)."""
        from sim.link import RoomClient
        acc = None
        with RoomClient(self.address) as rc:
            for _ in range(max(1, frames)):
                cap = rc.capture(0, not_before_rig_ns=not_before_ns, timeout_ms=20000, exposure=self.exposure)
                img = np.asarray(cap.image, np.float64)
                acc = img if acc is None else acc + img
        return (acc / max(1, frames)).astype(np.float32)


async def _wait(what: str, pred, timeout: float, *, step: float = 0.005):
    """Poll ``pred`` until it returns something truthy; TimeoutError naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} did not happen within {timeout:.0f} s")
        await asyncio.sleep(step)


def _room_command(args, light: Light, port: int) -> list[str]:
    """``shadowless room`` for the same room :func:`bench.uniformity_scenes.table_room` builds (same scales,
    seed and uneven light), a projector whose node's stream breaks off going black as a real one that
    lost its source."""
    return [sys.executable, "-m", "shadowless", "room", "--host", "127.0.0.1", "--port", str(port),
            "--projector-scale", str(args.projector_scale), "--camera-scale", str(args.camera_scale),
            "--seed", str(args.seed), "--brightness-spread", str(light.brightness_spread),
            "--white-spread", str(light.white_spread), "--hotspot", str(light.hotspot),
            "--vignetting", str(light.vignetting), "--no-signal", "black"]


@contextlib.contextmanager
def room_process(args, light: Light, work: Path, slots: list[str]):
    """The room as a process of its own (25 nodes' frames would starve a coordinator sharing its process),
    powering ``slots``; yields its address and its process id."""
    from shadowless.local import free_port
    from sim.link import RoomClient
    port = free_port()
    work.mkdir(parents=True, exist_ok=True)
    log = open(work / "room.log", "ab")
    proc = subprocess.Popen(_room_command(args, light, port), stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        address = f"127.0.0.1:{port}"
        with RoomClient(address) as rc:
            rc.wait_ready(300)
            rc.set_active(list(slots))
        yield address, proc.pid
    finally:
        stop_process(proc, timeout=20)
        log.close()


@contextlib.asynccontextmanager
async def live_rig(args, work: Path, light: Light, slots: list[str], *, watchdog: bool, show: str,
                   budgets=None):
    """The room (a process), a coordinator in this process and one node process per slot, blended, showing
    flat white (``show``: "timeline", a looping show at ``args.fps``, or "still"). ``Live.room`` is a twin
    of the room process built here the same way, for the truth only (footprints, what reaches where).
    ``budgets``: a :class:`shadowless.rig_budget.RigBudgets` every node process (restarts too) is put in."""
    from coordinator.app import CoordinatorApp
    from rigctl.job_command import ProgressView, run_job

    room = await asyncio.to_thread(table_room, light, projector_scale=args.projector_scale,
                                   camera_scale=args.camera_scale, seed=args.seed)
    room.set_active(slots)
    tw, th = room.scene.table.size
    content = (int(round(tw / 4)), int(round(th / 4)))
    params = blend_params({"headroom": "auto" if args.headroom is None else args.headroom,
                           **({} if args.map_scale is None else {"map_scale": args.map_scale})})
    with room_process(args, light, work, slots) as (address, room_pid):
        local = LocalRig(slots, work, output_size=room.projector_size(slots[0]), content_size=content,
                         node_output=f"room://{address}", mdns=False, latency_ms=80.0, budgets=budgets)
        local.create()
        rig = Rig(local.rig_dir)
        for s, lut in truth_luts(room, slots).items():
            H = room.truth.content_to_projector_homography(s, content)
            rig.update_slot(s, pose=HomographyPose(H / H[2, 2]), lut=lut, source="truth")
        _set_watchdog(local.rig_dir, watchdog, switch_lead_ms=getattr(args, "switch_lead_ms", None))
        if show == "timeline":
            _add_white_clip(local.rig_dir, work / "white", content, args.fps)
        rig = Rig(local.rig_dir)
        app = CoordinatorApp(rig, local.token, listen=f"127.0.0.1:{local.port}", advertise=False,
                             cameras=[f"room://{address}"])
        await app.start()
        try:
            t = time.perf_counter()
            for s in slots:
                local.start_node(s)
            async with await local.client() as c:
                await local.wait_live(c, timeout=600)
                _log(f"{len(slots)} nodes live ({time.perf_counter() - t:.0f} s)")
                view = ProgressView()         # progress on stderr
                await run_job(c, "calibrate", {"table_only": True, "table_points": points_doc(
                    table_points_from_truth(room, click_noise_px=0.3)), "settle_s": 0.0,
                    "table_mm": [float(v) for v in room.scene.table.size]}, view=view)
                t = time.perf_counter()
                result = await run_job(c, "blend", params, view=ProgressView())
                _log(f"{len(slots)} projectors blended through the nodes ({time.perf_counter() - t:.0f} s)")
                live = Live(room, address, local, app, c, list(slots), content, room_pid=room_pid)
                await _wait("the coordinator holding the new blend", lambda: _loaded(live, result), 60)
                if show == "timeline":
                    await _wait_holding(c, slots)
                    play = await c.play_asset("white", loop=True, delay_s=0.5)
                    live.shown_pts = int(getattr(play, "anchor_ns", 0) or 0)
                    await _wait("every node playing the show", lambda: _playing(live, slots), 120, step=0.05)
                else:
                    white = np.full((content[1], content[0], 3), 65535, np.uint16)
                    shown = await c.show(white, name="flat white")
                    live.shown_pts = int(getattr(shown, "pts_ns", 0))
                await _wait("every node showing the blend", lambda: live.showing_assigned(slots), 60)
                live.ahead_s = await _variants_ahead(live)
                live.exposure = await asyncio.to_thread(_exposure, live)
                live.result = result
                yield live
        finally:
            local.close()
            await app.stop()


def _exposure(live: Live) -> float:
    """A relative exposure at which the brightest lit pixel of the flat white sits near 0.85 of full scale."""
    e = 1.0
    for _ in range(6):
        live.exposure = e
        img = live.capture(1, not_before_ns=live.shown_pts)
        top = float(np.percentile(img.max(axis=-1), 99.9))
        if top < 0.95:
            return e * min(1.0, 0.85 / top) if top > 0 else e
        e /= 2
    return e


def _switched(live: Live) -> bool:
    """The coordinator shows the maps its state wants (no variant still being computed)."""
    state = getattr(live.core, "blending", None)
    if state is None or not hasattr(state, "wanted_key"):
        return True
    return state.applied == state.wanted_key()


def _loaded(live: Live, result: dict) -> bool:
    """The core took the blend the job stored (it reloads after the job; content shown before that reload
    would be followed by a switch of maps that changes nothing on screen)."""
    state = getattr(live.core, "blending", None)
    want = result.get("blend_id") if isinstance(result, dict) else None
    if state is None or not want:
        return True
    return state.blend_id == want and _switched(live)


async def _variants_ahead(live: Live, timeout: float = 600.0) -> float | None:
    """Wait until the coordinator holds the maps of every single loss (computed ahead in its worker
    threads, as it has long before a loss in a running show); the seconds it took from here, or None when
    this build computes none ahead."""
    variants = getattr(getattr(live.core, "blending", None), "variants", None)
    if variants is None or not hasattr(variants, "get"):
        return None
    from coordinator.blending.failover import variant_key
    t = time.perf_counter()
    held = getattr(variants, "held", variants.get)
    await _wait("the failover maps computed ahead", lambda: all(
        held(variant_key({s})) is not None or variants.failure(variant_key({s})) is not None
        for s in live.slots), timeout, step=0.1)
    return round(time.perf_counter() - t, 2)


def _add_white_clip(rig_dir: Path, folder: Path, content: tuple[int, int], fps: float) -> None:
    """A looping show of flat white (two identical frames as an image sequence) among the rig's assets."""
    import cv2
    from coordinator.assets import AssetStore
    folder.mkdir(parents=True, exist_ok=True)
    frame = np.full((content[1], content[0], 3), 255, np.uint8)
    for k in range(2):
        cv2.imwrite(str(folder / f"{k:03d}.png"), frame)
    AssetStore(rig_dir).add(folder, name="white", fps=fps, note=lambda *_: None)


async def _wait_holding(client, slots: list[str], timeout: float = 300.0) -> None:
    """Until every node of ``slots`` holds the show's asset."""
    deadline = time.monotonic() + timeout
    while True:
        st = await client.status()
        ok = {n.slot for n in st.nodes if n.assets_wanted >= 1 and n.assets_ready >= n.assets_wanted}
        if set(slots) <= ok:
            return
        if time.monotonic() > deadline:
            raise TimeoutError(f"nodes {sorted(set(slots) - ok)} never held the show's asset")
        await asyncio.sleep(0.2)


def _playing(live: Live, slots: list[str]) -> bool:
    """Every node's heartbeat says it plays the show."""
    for s in slots:
        sess = live.session(s)
        hb = None if sess is None else sess.heartbeat
        if hb is None or getattr(getattr(hb.show, "state", None), "value", hb.show.state) != "playing":
            return False
    return True


def _set_watchdog(rig_dir: Path, on: bool, *, switch_lead_ms: float | None = None) -> None:
    """rig.toml's ``[blend] watchdog`` (the failover part runs without it, so nothing else re-blends) and
    ``switch_lead_ms`` when given."""
    toml = rig_dir / "rig.toml"
    text = toml.read_text()
    keys = f"watchdog = {'true' if on else 'false'}"
    if switch_lead_ms is not None:
        keys += f"\nswitch_lead_ms = {float(switch_lead_ms)}"
    if "[blend]" in text:
        lines = [ln for ln in text.splitlines() if not ln.strip().startswith(("watchdog =", "switch_lead_ms ="))]
        text = "\n".join(lines).replace("[blend]", f"[blend]\n{keys}") + "\n"
    else:
        text = text.rstrip("\n") + f"\n\n[blend]\n{keys}\n"
    toml.write_text(text)


def _target(live: Live, headroom):
    """The flat white the blend of the whole rig means the camera to see, and where (``headroom`` as asked)."""
    size = live.room.camera_size(0)
    target, black, covered = stored_target(live.local.rig_dir, size, headroom=headroom)
    lit = live.room.truth.illumination_count(0) > 0
    if covered is None:
        return None, lit
    return target + black, covered & lit


async def _failover_one(args, work: Path, light: Light, name: str, slots: list[str], *, budgets=None) -> dict:
    victim = "r2c2" if "r2c2" in slots else slots[len(slots) // 2]
    period_ns = 1e9 / args.fps
    show = args.show if args.show != "auto" else ("timeline" if len(slots) <= 9 else "still")
    async with live_rig(args, work / name, light, slots, watchdog=False, show=show, budgets=budgets) as live:
        headroom = live.result.get("headroom") if isinstance(live.result, dict) else None
        target, covered = await asyncio.to_thread(_target, live, args.headroom)
        footprint = await asyncio.to_thread(lambda: live.room.truth.irradiance(victim, 0, occluders=False) > 0)
        before = await live.acapture(args.frames, not_before_ns=live.shown_pts)
        k = scale_of(before, target, covered)
        out: dict = {"slots": len(slots), "show": show, "lost": victim, "headroom": headroom,
                     "variants_ahead_s": live.ahead_s,
                     "before_loss": _r(nonuniformity(before, target, covered, within=footprint))}
        st = live.blend_status()
        out["state_before"] = st.state
        late0 = _late(live, slots)
        out["precomputed"] = _precomputed(live, victim)
        out.update(await _lose(live, victim, slots, period_ns, show, late0))
        after = await live.acapture(args.frames, not_before_ns=out.pop("_since"))
        out["after"] = _r(nonuniformity(after, target, covered, within=footprint, scale=k))
        out["after_own_scale"] = _r(nonuniformity(after, target, covered, within=footprint))
        out["light_kept"] = _r(scale_of(after, target, covered & footprint) / scale_of(before, target, covered & footprint), 4)
        _log(f"{name}: {victim} declared lost {out['detect_s']} s after the kill; new maps {out['frames_after_declared']} "
             f"frames later; non-uniformity in its footprint {out['after']}, light kept {out['light_kept']}")
        out["frame_period_ms"] = _r(period_ns / 1e6, 3)
        _log(f"{name}: {json.dumps(out)}")
        # the node returns (in its CPU budget, as any node start): the maps switch back
        back = await _come_back(args, live, victim, slots)
        out.update(back)
        if "_since" in back:
            got = await live.acapture(args.frames, not_before_ns=out.pop("_since"))
            out["after_return"] = _r(nonuniformity(got, target, covered, within=footprint, scale=k))
            # the same loss again, with the switch lead the coordinator learned from the switches before
            try:
                again = await _lose(live, victim, slots, period_ns, show, _late(live, slots))
                got = await live.acapture(args.frames, not_before_ns=again.pop("_since"))
                again["after"] = _r(nonuniformity(got, target, covered, within=footprint, scale=k))
                _log(f"{name}: the same loss again: new maps {again['frames_after_declared']} frames after it was "
                     f"declared (lead {again.get('switch_lead_ms')} ms); non-uniformity {again['after']}")
                await _come_back(args, live, victim, slots)
            except TimeoutError as exc:       # the figures of the first loss stand
                again = {"failed": str(exc)}
            out["again"] = again
            _log(f"{name}: {json.dumps(again)}")
        if budgets is not None:
            stats = budgets.stats()
            nodes = [v for k, v in stats.items() if k.startswith("node ")]
            out["budget"] = {**budgets.describe(), "nodes_throttled": sum(1 for st in nodes if st.get("throttled")),
                             "throttled_s": _r(sum(st.get("throttled_s", 0.0) for st in nodes), 3),
                             "node_cpu_s": _r(sum(st.get("cpu_s", 0.0) for st in nodes), 3),
                             "rasterizer_cpu_s": _r(sum(v.get("cpu_s", 0.0) for k, v in stats.items()
                                                        if k.startswith("rasterizer ")), 3)}
    return out


async def _lose(live: Live, victim: str, slots: list[str], period_ns: float, show: str, late0: dict) -> dict:
    """Kill ``victim``'s node process (its projector loses its signal) and follow the failover until every
    other node shows its new maps: the detection time, how many frames after the loss was declared the maps
    were on screen, the switch's timing and stages (``_since``: the pts the last node showed them from)."""
    old_ids = {s: live.slot_blend_id(s) for s in slots}
    rest = [s for s in slots if s != victim]
    cpu0 = await asyncio.to_thread(live.cpu_snapshot, rest)
    t_kill = time.monotonic_ns()
    live.local.nodes[victim].send_signal(signal.SIGKILL)
    # the room process blacks the dead node's projector out when its stream breaks off (--no-signal black)
    st = await _wait(f"{victim} declared lost", lambda: (lambda b: b if victim in b.lost else None)(
        live.blend_status()), 120)
    seen_ns = time.monotonic_ns()
    declared_ns = _declared_ns(st.since, seen_ns)
    out: dict = {"detect_s": _r((declared_ns - t_kill) / 1e9, 3), "message": st.message, "covered": st.covered}
    reported: dict[str, int] = {}       # slot -> when the coordinator first heard it shows its new maps

    def shown_everywhere() -> bool:
        for s in rest:
            sess, want = live.session(s), live.slot_blend_id(s)
            if s not in reported and want != old_ids[s] and sess is not None and sess.blend_id == want:
                reported[s] = time.monotonic_ns()
        return _switched(live) and any(live.slot_blend_id(s) != old_ids[s] for s in rest) \
            and live.showing_assigned(rest)
    await _wait("the remaining nodes showing new maps", shown_everywhere, 60)
    t_all = time.monotonic_ns()
    cpu2 = await asyncio.to_thread(live.cpu_snapshot, rest)     # read off the event loop, after the switch
    changed = [s for s in rest if live.slot_blend_id(s) != old_ids[s]]
    out["maps_changed"] = len(changed)
    since = live.since_ns(changed)
    out["frames_after_declared"] = _r(max(0.0, (max(since) - declared_ns) / period_ns), 2)
    out["switch_spread_ms"] = _r((max(since) - min(since)) / 1e6, 3)
    out["ms_after_declared"] = _r((max(since) - declared_ns) / 1e6, 2)
    out.update(_switch_timing(live, since, declared_ns, show, period_ns))
    out["stages_ms"] = _stages(live, changed, declared_ns, reported)
    # whose CPU the loss took, from the kill until every node was seen showing its maps (its detection too)
    out["cpu_ms"] = {"window_ms": _r((t_all - t_kill) / 1e6, 1), **cpu2.since(cpu0)}
    out["message_after"] = live.blend_status().message
    late1 = _late(live, rest)
    out["show_ticks_missed_meanwhile"] = sum(late1[s] - late0.get(s, 0) for s in rest)
    out["_since"] = max(since)
    return out


async def _come_back(args, live: Live, victim: str, slots: list[str]) -> dict:
    """Start ``victim``'s node again and wait until every node shows the whole rig's maps: how long that took
    (``_since``: the pts the last node showed them from), or why it did not happen."""
    t_back = time.monotonic_ns()
    live.local.start_node(victim)
    try:
        await _wait(f"{victim} back in the blend", lambda: victim not in live.blend_status().lost
                    and live.showing_assigned(slots), 180, step=0.05)
    except TimeoutError as exc:
        return {"switch_back_s": None, "after_return_note": str(exc)}
    since = live.since_ns(slots)
    out = {"switch_back_s": _r((max(since) - t_back) / 1e9, 2), "_since": max(since)}
    # the switch back's own timing: its lead (learned from the loss's switch, when the nodes were late
    # then) against when each node showed the maps, and where its time went
    state = getattr(live.core, "blending", None)
    wanted = int((getattr(state, "last_switch", None) or {}).get("wanted", 0))
    if wanted:
        period_ns = 1e9 / args.fps
        show = args.show if args.show != "auto" else ("timeline" if len(slots) <= 9 else "still")
        back = _switch_timing(live, since, wanted, show, period_ns)
        back.pop("instant_after_declared_ms", None)
        back["stages_ms"] = {k: v for k, v in _stages(live, slots, wanted, {}).items()
                             if not k.startswith("declared")}
        out["switch_back"] = back
    return out


def _switch_timing(live: Live, since: list[int], declared_ns: int, show: str, period_ns: float) -> dict:
    """The switch's lead and its common instant against what each node showed: how many heard too late
    (a still's node in time shows the maps at exactly the instant; a show's, from the first tick at or
    after it), how long after the declaration the coordinator set the switch, and how far after the
    instant the last node showed the maps."""
    state = getattr(live.core, "blending", None)
    at = int(getattr(state, "switched_at_ns", 0) or 0)
    if state is None or not at:
        return {}
    slack = 1_000_000 if show == "still" else period_ns
    late = [s - at for s in since if s - at > slack]
    lead = getattr(state, "last_lead_ns", None) or getattr(state, "lead_ns", 0) or 0
    parts = {k: _r(v / 1e6, 3) for k, v in (getattr(state, "last_lead_parts", None) or {}).items()}
    return {"switch_lead_ms": _r(lead / 1e6, 3), "lead_setting": "auto" if getattr(state, "lead_ns", 1) is None else "fixed",
            **({"lead_parts_ms": parts} if parts and getattr(state, "lead_ns", 1) is None else {}),
            "instant_after_declared_ms": _r((at - declared_ns) / 1e6, 2),
            "late_nodes": len(late), "nodes_switched": len(since),
            "last_after_instant_ms": _r((max(since) - at) / 1e6, 2),
            "late_after_instant_ms": sorted(_r(v / 1e6, 1) for v in late)}


#: a node's log line of its first swap with new maps (node/presenter.py), with the maps' way there
_TIMING = re.compile(r"blend (\S+) on screen from rig instant (\d+); timing instant=(\d+) received=(\d+) "
                     r"decoded=(\d+) presenter=(\d+) uploaded=(\d+)(?: ready=(\d+))? swapped=(\d+)")
#: the stages of a failover, in order: (name, the stamp it starts from, the stamp it ends at)
_STAGES = (("declared_to_wanted", "declared", "wanted"), ("wanted_to_ready", "wanted", "ready"),
           ("ready_to_set", "ready", "set"), ("set_to_received", "set", "received"),
           ("received_to_decoded", "received", "decoded"), ("decoded_to_presenter", "decoded", "presenter"),
           ("presenter_to_uploaded", "presenter", "uploaded"), ("uploaded_to_rendered", "uploaded", "rendered"),
           ("rendered_to_instant", "rendered", "instant"), ("uploaded_to_shown", "uploaded", "shown"),
           ("instant_to_shown", "instant", "shown"), ("shown_to_swapped", "shown", "swapped"),
           ("swapped_to_reported", "swapped", "reported"), ("declared_to_shown", "declared", "shown"))


def _stages(live: Live, slots: list[str], declared_ns: int, reported: dict[str, int]) -> dict:
    """Where one failover's time went, on the rig clock: per stage, its min, p50 and max over the nodes (ms).
    The coordinator's stamps (the loss declared, the variant wanted, ready, every assignment set, the common
    instant) are :attr:`coordinator.blending.state.BlendState.last_switch`; each node's (its network process
    received and decoded the maps, its presenter received and uploaded them, its first frame with them was
    rendered and finished ("rendered", its log's "ready"; ``rendered_to_instant`` below 0: after the instant,
    that node's frame was late),
    the pts of the first frame shown with them and when that swap was done) are its log line of that swap; "reported" is when this
    benchmark saw the node's heartbeat name the maps. A stage a node skipped (its maps came after the
    instant: shown at once) is still counted from its stamps."""
    state = getattr(live.core, "blending", None)
    common = dict(getattr(state, "last_switch", {}) or {})
    if not common:
        return {}
    common["declared"] = declared_ns
    common["instant"] = common.get("instant", 0)
    per: dict[str, list[float]] = {name: [] for name, _, _ in _STAGES}
    received: dict[str, float] = {}     # slot -> ms from the set to that node's network side having the maps
    found = 0
    for s in slots:
        want = live.slot_blend_id(s)
        rows = [m for m in _TIMING.finditer(live.local.log(f"node-{s}")) if m.group(1) == want]
        if not rows:
            continue
        found += 1
        m = rows[-1]
        stamps = dict(common, shown=int(m.group(2)), received=int(m.group(4)), decoded=int(m.group(5)),
                      presenter=int(m.group(6)), uploaded=int(m.group(7)), rendered=int(m.group(8) or 0),
                      swapped=int(m.group(9)))
        if s in reported:
            stamps["reported"] = reported[s]
        for name, a, b in _STAGES:
            if stamps.get(a) and stamps.get(b):
                per[name].append((stamps[b] - stamps[a]) / 1e6)
        if stamps.get("set") and stamps.get("received"):
            received[s] = (stamps["received"] - stamps["set"]) / 1e6
    out: dict = {"nodes": found}
    for name, _, _ in _STAGES:
        v = per[name]
        if v:
            out[name] = {"min": _r(min(v), 2), "p50": _r(float(np.median(v)), 2), "max": _r(max(v), 2)}
    if received:        # in the order the coordinator set them: a fan-out in that order, or the nodes' own turns
        out["set_to_received_by_slot"] = {s: _r(v, 1) for s, v in received.items()}
    return out


def _last_check(live: Live) -> dict | None:
    """The watchdog's last check: why it was skipped, or its fit's figures."""
    dog = getattr(live.core, "lamp_watchdog", None)
    last = getattr(dog, "last", None)
    if last is None:
        return None
    out = {"skipped": last.skipped, "checks": getattr(dog, "checks", None)}
    if not last.skipped:
        out.update(gains={s: _r(g, 4) for s, g in last.gains.items()}, condition=_r(last.condition, 2),
                   inliers=_r(last.inliers, 3), seconds=_r(last.seconds, 3))
    return out


def _precomputed(live: Live, victim: str) -> dict | None:
    """Whether the coordinator holds the maps for losing ``victim`` before the loss, and what its variants
    computed ahead hold (MiB)."""
    variants = getattr(getattr(live.core, "blending", None), "variants", None)
    if variants is None or not hasattr(variants, "get"):
        return None
    from coordinator.blending.failover import variant_key
    out = {"loss_ready": variants.get(variant_key({victim})) is not None,
           "held_mib": _r(variants.held_bytes() / 2 ** 20, 1)}
    if hasattr(variants, "ahead_counts"):
        out["ahead"] = variants.ahead_counts()
    return out


def _late(live: Live, slots: list[str]) -> dict[str, int]:
    """Each node's count of timeline ticks it missed, from its last heartbeat (how loaded the machine was)."""
    out = {}
    for s in slots:
        sess = live.session(s)
        hb = None if sess is None else sess.heartbeat
        out[s] = 0 if hb is None else int(hb.show.frames_late)
    return out


def _declared_ns(since_unix: float, seen_ns: int) -> int:
    """The rig-clock instant of a failover's start from its unix time (the status's ``since``), or the instant
    the benchmark saw it when the status carries none."""
    if since_unix and since_unix > 0:
        return int(time.monotonic_ns() - (time.time() - since_unix) * 1e9)
    return seen_ns


async def part_failover(args, work: Path, light: Light) -> dict:
    out = {}
    fraction = getattr(args, "cpu_budget", None)
    for name in [n.strip() for n in args.failover_rigs.split(",") if n.strip()]:
        slots = slots_of(name)
        key = "P9" if name in ("P9", "P9W") else name
        _log(f"failover: {name}, {len(slots)} node processes")
        out[key] = await _failover_one(args, work, light, name, slots)
        if fraction:
            share = round(0.75 * (os.cpu_count() or 1) / len(slots), 3) if fraction == "auto" else float(fraction)
            out[key]["cpu_budget"] = await _failover_budgeted(args, work, light, name, slots, share)
    return out


async def _failover_budgeted(args, work: Path, light: Light, name: str, slots: list[str], fraction: float) -> dict:
    """The same failover with each node process held to ``fraction`` of a core, its rasterizer's threads
    (llvmpipe: the GPU's stand-in, which a node's own GPU would run) in a group of their own without a
    limit, so that a node's CPU and the protocol are measured, not 25 software GPUs on a few cores; or
    why it could not run."""
    from shadowless.cpu_budget import CpuBudgetError
    from shadowless.rig_budget import RigBudgets
    # reserved (a high CFS weight): on a machine busy with other work the nodes still get their share
    budgets = RigBudgets(slots, node_cpu=fraction, node_gpu=None, period_ms=args.cpu_period_ms, reserve=True)
    why = budgets.check()
    if why:
        _log(f"failover: {why}")
        return {"skipped": why}
    _log(f"failover: {name} again, each node held to {fraction:g} of a core (its rasterizer apart)")
    try:
        with budgets:
            return await _failover_one(args, work, light, f"{name}-budget", slots, budgets=budgets)
    except CpuBudgetError as exc:
        _log(f"failover: {exc}")
        return {"skipped": str(exc)}
    except Exception as exc:        # a job or a wait the starved nodes failed: the shared-CPU figures stand
        _log(f"failover: {name} with the CPU budget: {type(exc).__name__}: {exc}")
        return {"failed": f"{type(exc).__name__}: {exc}"}


async def part_watchdog(args, work: Path, light: Light) -> dict:
    slots = slots_of("P25" if not args.quick else args.failover_rigs.split(",")[0])
    dim, dead = ("r1c1", "r3c3") if "r3c3" in slots else (slots[0], slots[-1])
    truth = {dim: 0.5, dead: 0.0}
    # the watchdog predicts the light of a still shown through the poses (a show changes under its capture)
    async with live_rig(args, work / "watchdog", light, slots, watchdog=True, show="still") as live:
        dog = getattr(live.core, "lamp_watchdog", None)
        if dog is None:
            raise Missing("the coordinator has no photometric watchdog (Coordinator.lamp_watchdog) in this build")
        target, covered = await asyncio.to_thread(_target, live, args.headroom)
        fp = await asyncio.to_thread(lambda: (live.room.truth.irradiance(dim, 0, occluders=False) > 0)
                                     | (live.room.truth.irradiance(dead, 0, occluders=False) > 0))
        k = scale_of(await live.acapture(args.frames, not_before_ns=live.shown_pts), target, covered)
        cfg = live.core.rig.config.blend
        out: dict = {"slots": len(slots), "interval_s": cfg.watchdog_interval_s, "truth": truth}
        # a check of the unchanged rig first: what the watchdog says with every lamp as new
        t = time.monotonic_ns()
        await _wait("a first watchdog check", lambda: dog.last is not None and dog.last.at_ns > t
                    and not dog.last.skipped, 60, step=0.02)
        out["before_change"] = _last_check(live)
        out["named_before_change"] = {s: _r(g, 4) for s, g in live.blend_status().lamps}
        t0 = time.monotonic_ns()         # the rig clock: this host's monotonic clock
        for s, g in truth.items():
            await asyncio.to_thread(live.set_lamp, s, g)
        named: dict[str, float] = {}
        gains: dict[str, float] = {}
        seen: set[int] = set()

        def poll():
            last = dog.last
            if last is not None and last.at_ns > t0 and not last.skipped and last.at_ns not in seen:
                seen.add(last.at_ns)
                for s in truth:        # named by a check whose capture came after the change
                    if s not in named and s in last.named:
                        named[s] = (time.monotonic_ns() - t0) / 1e9
                        # the fit's own estimate (the named gain is rounded to the re-blend's 1 % steps)
                        gains[s] = float(last.gains.get(s, last.named[s]))
            return len(named) == len(truth)

        try:
            await _wait("the watchdog naming both lamps", poll, 30, step=0.01)
        except TimeoutError as exc:
            out["timeout"] = str(exc)
        st = live.blend_status()
        out["last_check"] = _last_check(live)
        out["checks_after_change"] = len(seen)
        out["named_s"] = {s: _r(v, 3) for s, v in named.items()}
        out["estimates"] = {s: _r(gains.get(s), 4) for s in truth}
        out["message"] = st.message
        out["detect_s"] = _r(max(named.values()), 3) if len(named) == len(truth) else None
        errs = [abs(gains[s] - truth[s]) for s in truth if s in gains]
        out["gain_error"] = _r(max(errs), 4) if len(errs) == len(truth) else None
        try:
            if not named:
                raise TimeoutError("no lamp named: nothing re-blended")
            t = time.monotonic_ns()
            await _wait("the re-blend switched", lambda: _switched(live), 60)
            out["reblend_after_named_s"] = _r((time.monotonic_ns() - t) / 1e9, 3)
            st = live.blend_status()
            rest = [s for s in slots if s not in st.lost]
            await _wait("nodes showing the re-blended maps", lambda: live.showing_assigned(rest), 60)
            since = live.since_ns(rest)
            after = await live.acapture(args.frames, not_before_ns=max(since))
            out["after"] = _r(nonuniformity(after, target, covered, within=fp, scale=k))
            out["after_own_scale"] = _r(nonuniformity(after, target, covered, within=fp))
            out["light_kept"] = _r(scale_of(after, target, covered & fp) / k, 4)
        except TimeoutError as exc:
            out["after"] = None
            out["after_note"] = str(exc)
        _log(f"watchdog: named {out['named_s']}, estimates {out['estimates']}, footprints {out.get('after')}")
    return out


def _r(v, nd: int = 5):
    if v is None:
        return None
    v = float(v)
    return None if np.isnan(v) else round(v, nd)
