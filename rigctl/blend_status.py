"""What `shadowless status` says of the rig's per-pixel blend and of any failover.

:func:`blend_dict` is the ``blend`` object of ``status --json`` (instants as unix times, ages in
seconds against the operator's clock, null when there is none); :func:`blend_lines` is the text:
one line for the blend (``blend: measured 2.0 h ago, headroom 8 % (costs 8 % of brightness)``, or
how to make one), one for a failover (``failover: r2c3 lost 12 s ago: 24 projectors cover its
footprint, uniformity kept``) and one per lamp the photometric watchdog named with its estimated
gain. The console says the same on its page (``coordinator/console/static/blend.js``).
"""
from __future__ import annotations

from coordinator.api import BlendStatus

#: what an operator runs to measure a blend (said wherever there is none)
MAKE_BLEND = "shadowless blend RIG"


def ago(seconds: float) -> str:
    """A duration as an operator reads it: ``12 s``, ``5 min``, ``2.0 h``, ``3 d``."""
    s = max(0.0, float(seconds))
    if s < 90:
        return f"{s:.0f} s"
    if s < 90 * 60:
        return f"{s / 60:.0f} min"
    if s < 48 * 3600:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.0f} d"


def _pct(x: float) -> str:
    """A fraction as a whole percentage, or with one decimal below 10 % (``0.084`` -> ``8.4 %``)."""
    p = 100.0 * x
    return f"{p:.1f} %" if abs(p) < 10 and round(p, 1) != round(p) else f"{p:.0f} %"


def blend_dict(b: BlendStatus, *, now: float) -> dict:
    """The blend as JSON. ``now``: the operator's unix time, for the ages."""
    return {
        "state": b.state, "blend_id": b.blend_id,
        "created_at": b.created_at or None, "age_s": round(now - b.created_at, 1) if b.created_at else None,
        "headroom": round(b.headroom, 4), "brightness_cost": round(b.brightness_cost, 4),
        "lost": list(b.lost), "since": b.since or None,
        "lost_for_s": round(now - b.since, 1) if b.since else None,
        "covered": b.covered, "lamps": [{"slot": s, "gain": round(g, 4)} for s, g in b.lamps],
        "message": b.message,
    }


def failover_line(d: dict) -> str:
    """The failover in one line: the coordinator's own words when it gave them (they count the
    projectors that cover the lost footprints), else made from the fields; whether uniformity is
    kept is said either way."""
    kept = "uniformity kept" if d["covered"] else "uniformity NOT kept: part of the lost light has no other projector"
    message = d["message"].strip()
    if message:
        return f"failover: {message}" + ("" if "uniformity" in message else f", {kept}")
    when = f" {ago(d['lost_for_s'])} ago" if d["lost_for_s"] is not None else ""
    whose = "its footprint" if len(d["lost"]) <= 1 else "their footprints"
    cover = f"the others cover {whose}" if d["covered"] else f"the others do not cover all of {whose}"
    dimmed = [f"lamp of {x['slot']} at {_pct(x['gain'])}" for x in d["lamps"] if x["slot"] not in d["lost"]]
    who = ", ".join(([f"{', '.join(d['lost'])} lost"] if d["lost"] else []) + dimmed) or "a projector lost"
    return f"failover: {who}{when}: {cover}, {kept}"


def blend_lines(d: dict) -> list[str]:
    """`shadowless status`'s lines about the blend (``d``: :func:`blend_dict`)."""
    message = d["message"].strip()
    if d["state"] == "none":
        lines = [f"blend: none (each projector at one gain, no failover): measure one with `{MAKE_BLEND}`"]
        if message and "shadowless blend" not in message:        # why a stored blend is not in use
            lines.append(f"blend: {message}")
        return lines
    measured = f"measured {ago(d['age_s'])} ago" if d["age_s"] is not None else "measured (time unknown)"
    note = message.partition("; ")[2] if d["state"] == "blended" else ""    # e.g. no contributions: no failover
    lines = [f"blend: {measured}, headroom {_pct(d['headroom'])} (costs {_pct(d['brightness_cost'])} of brightness)"
             + (f"; {note}" if note else "")]
    if d["state"] == "failover" or d["lost"]:
        lines.append(failover_line(d))
    for lamp in d["lamps"]:
        g = lamp["gain"]
        what = "dark" if g < 0.05 else "dimmed" if g < 1 else "brighter than measured"
        lines.append(f"lamp {lamp['slot']} {what}: estimated gain {g:.2f} (photometric watchdog)")
    return lines
