"""`shadowless bench console`'s cue figures: how long GO takes to reach every projector, and how
closely the nodes agree during a crossfade.

On the bench's rig (a coordinator in a thread of this process, offscreen node processes on this
host), a cue list alternates the rig's content and black, as cuts and as crossfades. The node
reports are read as they reach the core (every swap: its frame id and the host's monotonic clock,
which is the rig clock's truth since the nodes share the host):

* ``go_to_swap_ms``: from the GO call to the swap of the cue's first frame on the last node
  (target: at most one frame at 60 Hz plus the latency budget); a node that dropped the frame as
  late shows it when the coordinator sends it again with twice the budget, which counts
  (``go_resent_after_a_late_drop`` says how often);
* ``crossfade_skew_ms``: for every step of every crossfade shown by every node, the latest swap
  less the earliest (target p99: 2 ms).
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from coordinator.rig import Content
from protos.cues import Cue, CueList

#: one frame at 60 Hz, ms
FRAME_MS = 1000.0 / 60.0
#: the skew target for a crossfade's steps, ms
SKEW_TARGET_MS = 2.0


class SwapLog:
    """Every swap the nodes report to the core: (slot, frame id) -> host monotonic ns. Installed on
    the core's ``on_report`` (the node service calls it for each report) until :meth:`close`; read
    it in the core's loop (``rig.call``), where it is written."""

    def __init__(self, coord: Any):
        self.coord = coord
        self.swaps: dict[tuple[str, int], int] = {}
        self._orig = coord.on_report

        def spy(sess, rep):
            for fid, host in zip(rep.swaps.frame_id.tolist(), rep.swaps.host_monotonic_ns.tolist()):
                self.swaps[(sess.slot, int(fid))] = int(host)
            return self._orig(sess, rep)

        coord.on_report = spy

    def close(self) -> None:
        self.coord.on_report = self._orig

    def swapped(self, frame_id: int, slots: list[str]) -> list[int] | None:
        """The host instants every slot swapped ``frame_id`` (None until all did)."""
        got = [self.swaps.get((s, frame_id)) for s in slots]
        return None if any(g is None for g in got) else got

    def first_from(self, frame_id: int, slots: list[str]) -> list[int] | None:
        """Per slot, the first swap of ``frame_id`` or a later frame (a still dropped late is sent
        again under a new id); None until every slot swapped one."""
        firsts: dict[str, int] = {}
        for (slot, fid), host in list(self.swaps.items()):
            if fid >= frame_id and (slot not in firsts or host < firsts[slot]):
                firsts[slot] = host
        return [firsts[s] for s in slots] if all(s in firsts for s in slots) else None


def _p(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


def cue_figures(rig: Any, slots: list[str], *, rounds: int = 10, fade_s: float = 1.0, timeout_s: float = 30.0) -> dict:
    """Fire ``rounds`` cuts and ``rounds`` crossfades of ``fade_s`` on ``rig`` (bench.console's
    ConsoleRig, every node in ``slots`` live); the figures as a JSON-able dict."""
    coord = rig.coord
    w, h = coord.content_size
    y, x = np.mgrid[0:h, 0:w]
    image = np.stack([x * 255 // max(1, w - 1), y * 255 // max(1, h - 1), np.full_like(x, 128)], axis=2)
    image = image.astype(np.uint8)
    rig.call(lambda: coord.show(Content(image, name="bench cues"), persist=True))
    cues = []
    for k in range(rounds):
        cues += [Cue(f"c{k}", "", "still", "content"), Cue(f"b{k}", "", "blackout")]
    for k in range(rounds):
        cues += [Cue(f"fc{k}", "", "still", "content", fade_s=fade_s), Cue(f"fb{k}", "", "blackout", fade_s=fade_s)]
    rig.call(lambda: coord.set_cues(CueList(tuple(cues)), who="bench"))
    log = rig.call(lambda: SwapLog(coord))
    go_ms: list[float] = []
    skews: list[float] = []
    steps_seen = steps_all = resent = 0
    try:
        for i, cue in enumerate(cues):
            before = rig.call(lambda: coord.playback.current_frame.frame_id if coord.playback.current_frame else 0)
            t_go = time.monotonic_ns()
            rig.call(lambda: coord.cue_go(who="bench"))
            deadline = time.monotonic() + timeout_s
            while True:     # the cue's frame (its fire runs on after the call)
                frame = rig.call(lambda: coord.playback.current_frame)
                if frame is not None and frame.frame_id != before and frame.tag == f"show:cue:{cue.id}":
                    break
                if time.monotonic() > deadline:
                    raise TimeoutError(f"cue {cue.id} sent no frame in {timeout_s:g} s")
                time.sleep(0.002)
            last = frame.frame_id + frame.fade_steps
            while rig.call(lambda: log.first_from(last, slots)) is None:     # its last step on every projector
                if time.monotonic() > deadline:
                    raise TimeoutError(f"cue {cue.id}: not every node showed frame {last} in {timeout_s:g} s")
                time.sleep(0.01)
            time.sleep(0.05)
            if not cue.fade_s:
                resent += rig.call(lambda: log.swapped(frame.frame_id, slots)) is None    # a node dropped it late
                go_ms.append((max(rig.call(lambda: log.first_from(frame.frame_id, slots))) - t_go) / 1e6)
            if cue.fade_s:
                for k in range(frame.fade_steps + 1):
                    steps_all += 1
                    got = rig.call(lambda: log.swapped(frame.frame_id + k, slots))
                    if got is not None:
                        steps_seen += 1
                        skews.append((max(got) - min(got)) / 1e6)
    finally:
        rig.call(log.close)
    latency_ms = coord.latency_ns / 1e6
    return {
        "cues": {"rounds": rounds, "fade_s": fade_s, "latency_budget_ms": latency_ms,
                 "go_to_swap_target_ms": round(FRAME_MS + latency_ms, 1),
                 "go_to_swap_ms_p50": _p(go_ms, 50), "go_to_swap_ms_max": _p(go_ms, 100),
                 "go_resent_after_a_late_drop": resent,
                 "crossfade_steps": steps_all, "crossfade_steps_shown_by_all": steps_seen,
                 "crossfade_skew_ms_p50": _p(skews, 50), "crossfade_skew_ms_max": _p(skews, 100),
                 "crossfade_skew_target_ms": SKEW_TARGET_MS},
        "go_to_swap_ms_p99": _p(go_ms, 99),
        "crossfade_skew_ms_p99": _p(skews, 99),
    }
