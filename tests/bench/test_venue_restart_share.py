"""bench/venue_show.py ``restart_share``: what a coordinator restart itself cost, the nodes' own rate of
missed ticks before the kill taken off the misses from the kill on (the whole bench runs in
tests/bench/test_venue.py)."""
from __future__ import annotations

from bench.venue_show import restart_share


def _phases(*after: tuple[int, int, int]) -> dict:
    return {f"n{i}": {"before_kill": b, "outage": o, "after_restart": a} for i, (b, o, a) in enumerate(after)}


def test_the_restart_share_is_the_misses_from_the_kill_on_less_the_background_rate():
    # 2 misses in 600 node-ticks before the kill; from it on 5 + 3 misses (the second before the kill is not counted)
    out = restart_share(2, 600, _phases((1, 2, 3), (0, 0, 3)), 900)
    assert out["background"] == {"ticks": 600, "missed": 2, "per_tick": round(2 / 600, 5)}
    assert out["frames_missed_after_kill"] == 8 and out["ticks_after_kill"] == 900
    assert out["frames_missed_restart_share"] == 5.0          # 8 - 900 * 2 / 600


def test_a_restart_that_missed_fewer_than_the_background_says_so_and_no_background_no_share():
    assert restart_share(6, 600, _phases((0, 1, 1)), 900)["frames_missed_restart_share"] == -7.0
    out = restart_share(0, 0, _phases((0, 0, 1)), 300)
    assert out["background"]["per_tick"] is None and out["frames_missed_restart_share"] is None
    assert out["frames_missed_after_kill"] == 1
