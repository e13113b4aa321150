"""The console's health banner, as data: counts (projectors live of those expected, slots without a
pose) and alarms (lost nodes and since when, frames missed lately, clocks not settled, assets not
ready, recent refusals, a failover), each with a level, from one :class:`RigStatus`.

Part of the page's snapshot (key ``health``, see :mod:`coordinator.console.live`), which is pushed
only when it changes: nothing here counts time. Instants are Unix times (``since``), which the page
turns into "12 s ago" itself; figures that move every instant are left out or rounded.
"""
from __future__ import annotations

import math
import time
from typing import Any

from coordinator.api import NodeState, RigStatus
from coordinator.identify import identify_marks

#: refusals newer than this count as recent (seconds)
RECENT_REFUSAL_S = 300.0
#: a node's clock error (measured on the coordinator's host) over this is an alarm (ms)
CLOCK_ERROR_MS = 1.0
#: at most this many alarms of one kind are listed one by one; the rest are summed up
MAX_LISTED = 8
LEVELS = ("ok", "warn", "alarm")


def _plural(n: int, word: str, many: str | None = None) -> str:
    return f"{n} {word if n == 1 else (many or word + 's')}"


def _names(slots: list[str]) -> str:
    """"r1c1, r1c2" or, past :data:`MAX_LISTED`, "24 projectors (r1c1, r1c2, … and 16 more)"."""
    if len(slots) <= MAX_LISTED:
        return ", ".join(slots)
    return f"{len(slots)} projectors ({', '.join(slots[:MAX_LISTED])} and {len(slots) - MAX_LISTED} more)"


def _alarm(level: str, kind: str, text: str, *, slots: list[str] | None = None,
           since: float | None = None) -> dict[str, Any]:
    return {"level": level, "kind": kind, "text": text, "slots": slots or [],
            "since": round(since) if since is not None else None}


def health_view(status: RigStatus, *, now: float | None = None) -> dict[str, Any]:
    """The banner's data: ``level`` ("ok", "warn", "alarm": the worst alarm's), ``counts``,
    ``alarms`` (worst first; each ``level``, ``kind``, one line of ``text``, the ``slots`` it is
    about and ``since``, a Unix time or None; a solo, a test pattern or name cards on the
    projectors are a warning too), the ``unposed_warning`` line (as the command line prints it)
    and each slot's identify ``marks`` (number and colour)."""
    now = time.time() if now is None else now
    nodes = status.nodes
    by_state = {s: [n for n in nodes if n.state == s] for s in NodeState}
    live = by_state[NodeState.LIVE]
    unposed = [n.slot for n in nodes if n.pose_kind == "none"]
    counts = {"slots": len(nodes), "live": len(live), "joined": len(by_state[NodeState.JOINED]),
              "lost": len(by_state[NodeState.LOST]), "expected": len(by_state[NodeState.EXPECTED]),
              "unposed": len(unposed)}
    alarms: list[dict[str, Any]] = []

    b = status.blend
    if b.state == "failover":
        verdict = b.message.partition(": ")[2].strip() or b.message
        alarms.append(_alarm("alarm" if not b.covered else "warn", "failover",
                             f"failover: {_names(list(b.lost))} out of the blend; {verdict}", slots=list(b.lost),
                             since=b.since or None))

    lost = sorted(by_state[NodeState.LOST], key=lambda n: -n.last_seen_age_ms)
    for n in lost[:MAX_LISTED]:
        alarms.append(_alarm("alarm", "lost", f"{n.slot} left ({n.left})" if n.left else f"{n.slot} lost (its node went silent)", slots=[n.slot],
                             since=now - n.last_seen_age_ms / 1e3))
    if len(lost) > MAX_LISTED:
        rest = [n.slot for n in lost[MAX_LISTED:]]
        alarms.append(_alarm("alarm", "lost", f"{_plural(len(rest), 'more projector')} lost: {', '.join(rest)}",
                             slots=rest))

    missing = [n.slot for n in by_state[NodeState.EXPECTED]]
    if missing:
        alarms.append(_alarm("warn", "missing", f"{_plural(len(missing), 'projector')} never connected: "
                             f"{_names(missing)} (start their nodes, or check the network)", slots=missing))

    if status.late_recent:
        window = "minute" if status.late_window_s >= 55 else f"{max(1, round(status.late_window_s))} s"
        parts = [f"{s} {n}" for s, n in sorted(status.late_recent, key=lambda t: -t[1])[:MAX_LISTED]]
        total = sum(n for _, n in status.late_recent)
        alarms.append(_alarm("warn", "late", f"{_plural(total, 'frame')} missed (late or dropped) in the last "
                             f"{window}: {', '.join(parts)}", slots=[s for s, _ in status.late_recent]))

    unsettled, off = [], []
    for n in live:
        if n.clock_rtt_ms == 0.0 or n.clock_drift_ppm == 0.0:
            unsettled.append(n.slot)        # no exchange yet, or too few to fit the drift (about 20 s)
        elif math.isfinite(n.clock_error_ms) and abs(n.clock_error_ms) > CLOCK_ERROR_MS:
            off.append(n.slot)
    if unsettled:
        alarms.append(_alarm("warn", "clock", f"clock not settled yet on {_names(unsettled)} (a node fits its "
                             "clock over about 20 s after it joins)", slots=unsettled))
    if off:
        alarms.append(_alarm("alarm", "clock", f"clock off by more than {CLOCK_ERROR_MS:g} ms on {_names(off)}",
                             slots=off))

    for n in live:          # the node keeps the assignment before: the projector shows what it showed
        if n.assignment_refused:
            alarms.append(_alarm("alarm", "assignment", f"{n.slot} refused assignment {n.assignment_refused}; it "
                                 f"still shows r{n.assignment_revision}", slots=[n.slot]))

    fetching = []
    for n in live:
        failed = [a for a in n.assets if a.error]
        for a in failed:
            alarms.append(_alarm("alarm", "assets", f"{n.slot} gave up on asset {a.name or a.asset_id[:12]}: "
                                 f"{a.error}", slots=[n.slot]))
        if n.assets_ready < n.assets_wanted:
            pct = 100.0 * n.asset_bytes_have / n.asset_bytes_total if n.asset_bytes_total else 0.0
            fetching.append((n.slot, f"{n.slot} {n.assets_ready}/{n.assets_wanted} ({math.floor(pct)} %)"))
    if fetching:
        alarms.append(_alarm("warn", "assets", "assets not ready on " + ", ".join(t for _, t in fetching[:MAX_LISTED])
                             + (f" and {len(fetching) - MAX_LISTED} more" if len(fetching) > MAX_LISTED else ""),
                             slots=[s for s, _ in fetching]))

    recent = [r for r in status.refusals if r.age_s <= RECENT_REFUSAL_S]
    if recent:
        newest = min(recent, key=lambda r: r.age_s)
        total = sum(r.count for r in recent)
        alarms.append(_alarm("warn", "refusals", f"{_plural(total, 'refusal')} in the last 5 min, the newest from "
                             f"{newest.peer}{' for ' + newest.slot if newest.slot else ''}: {newest.reason}",
                             slots=sorted({r.slot for r in recent if r.slot}), since=now - newest.age_s))

    # the operator's own tools leave projectors dark or showing what the audience should not see
    showing = status.showing
    if showing.startswith("solo "):
        alarms.append(_alarm("warn", "solo", f"{showing} (the others are black: End solo, or the next show, ends it)"))
    elif showing.startswith("test pattern "):
        alarms.append(_alarm("warn", "pattern", f"{showing} (Stop or the next show ends it)"))
    elif showing == "slot names (identify)":
        alarms.append(_alarm("warn", "identify", "every projector shows its name card (Stop or the next show ends it)"))

    alarms.sort(key=lambda a: -LEVELS.index(a["level"]))
    level = alarms[0]["level"] if alarms else "ok"
    return {"level": level, "counts": counts, "alarms": alarms, "unposed_warning": status.unposed_warning,
            "marks": identify_marks([n.slot for n in nodes])}
