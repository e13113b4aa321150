"""The MIDI timecode chase in `shadowless bench show_control`: how close a playing show stays to MTC.

A coordinator (no nodes) plays a 25 fps clip. A thread sends MTC at 25 fps as a sender would (a
quarter frame every 10 ms, eight of them per two frames), starting 3 s ahead of the show, through
:meth:`coordinator.osc.mtc_input.MtcInput.feed`: the entry rtmidi's callback thread calls, so the
whole path from bytes to the show's timeline is the product's own; only the MIDI port is left out
(a machine without an ALSA sequencer has none). Every 50 ms the show's position is compared with
the MTC clock. Then MTC stops and the show must play on by itself: no seek in the next 2 s.

Figures: the chase's seeks (one is expected: the 3 s jump), the drift the first seek corrected,
and the absolute error between the show and MTC once settled (after 1.5 s), in ms. The error
includes the sender thread's own pacing delay (it sleeps in 0.5 ms steps), so it is an upper
bound on the chase's.
"""
from __future__ import annotations

import asyncio
import statistics
import threading
import time
from pathlib import Path

FPS = 25
AHEAD_FRAMES = 3 * FPS          # MTC starts 3 s ahead of the show: the chase must seek once
SETTLE_S = 1.5                  # errors before this are the seek itself
QUIET_AFTER_S = 2.0             # the show plays on alone this long once MTC stops


def _clip(folder: Path, frames: int) -> Path:
    import cv2
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    for k in range(frames):
        cv2.imwrite(str(folder / f"{k:04d}.png"), np.full((16, 32, 3), k % 128 * 2, np.uint8))
    return folder


def _pct(values: list[float], p: float) -> float:
    s = sorted(values)
    return round(s[min(len(s) - 1, int(p / 100 * len(s)))], 3)


async def measure(workdir: Path, seconds: float) -> dict:
    """Run the chase for ``seconds`` of MTC on a fresh rig under ``workdir``; return the figures."""
    from coordinator.app import CoordinatorApp
    from coordinator.assets import AssetStore
    from coordinator.console.audit import ActionLog
    from coordinator.osc.config import load_osc
    from coordinator.osc.mtc import from_frame_number, quarter_frames
    from coordinator.osc.mtc_input import MtcInput
    from coordinator.osc.timecode import show_position
    from coordinator.rig import Rig, grid_slots, init_rig

    rig_dir = init_rig(workdir / "mtc-rig", name="mtc", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32, force=True)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\n')
    # long enough to outlast the run: the 3 s jump, the MTC, the quiet time after, and a margin
    frames = int((AHEAD_FRAMES / FPS + seconds + QUIET_AFTER_S + 3) * FPS)
    AssetStore(rig_dir).add(_clip(workdir / "mtc-clip", frames), name="clip", fps=FPS)

    def chase_seeks() -> list[dict]:
        return [e for e in ActionLog(rig_dir).entries if e.get("action") == "mtc timecode chase"]

    app = CoordinatorApp(Rig(rig_dir), b"m" * 32, listen="127.0.0.1:0", advertise=False)
    await app.start()
    stop = threading.Event()
    sender: threading.Thread | None = None
    try:
        coord = app.coordinator
        port = MtcInput("bench", app.osc.mtc_readings, coord.rig_now)
        coord.play_asset("clip")
        deadline = time.monotonic() + 30
        while coord.status().show.state != "playing":
            if time.monotonic() > deadline:
                raise RuntimeError(f"the clip did not start playing in 30 s: {coord.status().show}")
            await asyncio.sleep(0.01)
        start_frame = int(show_position(coord.status().show, coord.rig_now())) + AHEAD_FRAMES
        t0 = coord.rig_now()
        m0 = time.monotonic_ns()

        def send() -> None:
            q = 0
            while not stop.is_set():
                due = m0 + q * 10_000_000
                while time.monotonic_ns() < due and not stop.is_set():
                    time.sleep(0.0005)
                group, piece = divmod(q, 8)
                port.feed(quarter_frames(from_frame_number(start_frame + 2 * group, 1))[2 * piece:2 * piece + 2])
                q += 1

        sender = threading.Thread(target=send, name="mtc-sender", daemon=True)
        sender.start()
        errors: list[tuple[float, float]] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            await asyncio.sleep(0.05)
            now = coord.rig_now()
            mtc_s = start_frame / FPS + (now - t0) / 1e9
            errors.append(((now - t0) / 1e9, (show_position(coord.status().show, now) / FPS - mtc_s) * 1e3))
        stop.set()
        sender.join()
        seeks = chase_seeks()
        await asyncio.sleep(QUIET_AFTER_S)       # a bench, not a test: the quiet time is the measurement
        seeks_after = len(chase_seeks()) - len(seeks)
        still_playing = coord.status().show.state == "playing"
    finally:
        stop.set()
        if sender is not None:
            sender.join()
        await app.stop()
    settled = [abs(e) for t, e in errors if t > SETTLE_S]
    if not settled:
        raise RuntimeError(f"no sample after {SETTLE_S} s: run longer than {seconds} s")
    return {"mtc_fps": FPS, "mtc_seconds": seconds, "samples_settled": len(settled),
            "chase_threshold_ms": load_osc(rig_dir).chase_threshold_ms,
            "seeks": len(seeks), "first_seek_drift_ms": seeks[0]["params"].get("drift_ms") if seeks else None,
            "abs_error_ms_p50": round(statistics.median(settled), 3), "abs_error_ms_p99": _pct(settled, 99),
            "abs_error_ms_max": round(max(settled), 3),
            "seeks_after_mtc_stopped": seeks_after, "quiet_after_s": QUIET_AFTER_S,
            "show_still_playing_after": still_playing}
