"""How numbers read to an operator: counts with their noun in the right number ("1 projector",
"3 projectors"), durations and ages in human units ("2 min 5 s", "0.2 s ago") and wall-clock
times ("14:02:03"). One place for every process's messages, so each says it the same way."""
from __future__ import annotations

import math
import time

__all__ = ["plural", "count", "duration", "ago", "wall_time"]

#: nouns whose plural is not the noun with an s
_IRREGULAR = {"was": "were", "has": "have", "is": "are", "this": "these", "it": "they", "mesh": "meshes",
              "patch": "patches", "match": "matches", "pass": "passes", "index": "indices"}


def plural(n: int | float, noun: str, many: str | None = None) -> str:
    """``noun`` as it goes with the count ``n``: the singular for exactly 1, else ``many`` (default:
    the noun's usual plural)."""
    if n == 1:
        return noun
    return many or _IRREGULAR.get(noun) or (noun[:-1] + "ies" if noun.endswith("y") and noun[-2:-1] not in "aeiou"
                                            else noun + "s")


def count(n: int, noun: str, many: str | None = None) -> str:
    """``"1 projector"``, ``"3 projectors"``, ``"0 projectors"``."""
    return f"{n} {plural(n, noun, many)}"


def duration(seconds: float) -> str:
    """A span in the units an operator reads: ``"0.2 s"``, ``"42 s"``, ``"2 min 5 s"``, ``"3 h 4 min"``,
    ``"2 d 3 h"``; ``"-"`` for NaN or infinity."""
    if not math.isfinite(seconds):
        return "-"
    s = abs(seconds)
    if s < 10:
        return f"{s:.1f} s"
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        m, r = divmod(int(round(s)), 60)
        return f"{m} min {r} s" if r else f"{m} min"
    if s < 86400:
        h, r = divmod(int(round(s)) // 60, 60)
        return f"{h} h {r} min" if r else f"{h} h"
    d, r = divmod(int(round(s)) // 3600, 24)
    return f"{d} d {r} h" if r else f"{d} d"


def ago(seconds: float) -> str:
    """``"0.2 s ago"``, ``"4 min 10 s ago"`` (``"-"`` when unknown)."""
    return "-" if not math.isfinite(seconds) else f"{duration(seconds)} ago"


def wall_time(unix_s: float, *, now: float | None = None) -> str:
    """The local clock time of ``unix_s``: ``"14:02:03"`` on the day of ``now`` (default: this
    machine's clock), ``"Dec 05 14:02:03"`` on another day."""
    if not math.isfinite(unix_s):
        return "-"
    now = time.time() if now is None else now
    t, today = time.localtime(unix_s), time.localtime(now)
    same_day = (t.tm_year, t.tm_yday) == (today.tm_year, today.tm_yday)
    return time.strftime("%H:%M:%S" if same_day else "%b %d %H:%M:%S", t)
