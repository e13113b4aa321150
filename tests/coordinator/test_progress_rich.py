"""Progress drawn with rich: a job's bars (done/total, percentage, ETA) and upload bytes. A log
(not a terminal) gets plain lines at each 10 %, never carriage-return redraws."""
from __future__ import annotations

import asyncio
import io
import threading

import pytest
import rich.console

from rigctl import content_format
from rigctl.content_format import Progress as ByteProgress
from rigctl.job_command import ProgressView, run_job
from coordinator.jobs.context import Progress


class Clock:
    """rich's clock, set by the test."""

    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(rich.console, "monotonic", c)       # what each new Console (and its bars) reads
    return c


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def live_threads() -> list[threading.Thread]:
    """rich's live-display threads not told to stop."""
    return [t for t in threading.enumerate() if type(t).__name__ == "_RefreshThread" and not t.done.is_set()]


def test_a_job_in_a_log_gets_a_line_per_tenth_with_its_eta(clock):
    out = io.StringIO()
    view = ProgressView(out)
    for k in range(11):                                    # 2 s per pattern
        clock.now = 1000.0 + 2 * k
        view.event(Progress(stage="gray codes", item="r0c0", done=k, total=10, message="gray codes"))
    view.event("camera exposure fine")
    for n in range(4):                                     # one count over the slots, each named in turn
        clock.now = 1100.0 + 5 * n
        view.event(Progress(stage="response", item=f"r0c{n}", done=n + 1, total=4, message="fitted, gamma 2.20", value=2.2))
    view.close()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue() and "\x1b" not in out.getvalue()
    assert lines[0] == "gray codes r0c0: 0/10 (0%), 0:00:00 elapsed, ETA ?  gray codes"
    assert "gray codes r0c0: 5/10 (50%), 0:00:10 elapsed, ETA 0:00:10  gray codes" in lines
    assert "gray codes r0c0: 9/10 (90%), 0:00:18 elapsed, ETA 0:00:02  gray codes" in lines
    assert lines[10:12] == ["gray codes r0c0: 10/10 (100%), in 0:00:20  gray codes", "camera exposure fine"]
    assert lines[12:] == ["response r0c0: 1/4 (25%), 0:00:00 elapsed, ETA ?  fitted, gamma 2.20",
                          "response r0c1: 2/4 (50%), 0:00:05 elapsed, ETA ?  fitted, gamma 2.20",
                          "response r0c2: 3/4 (75%), 0:00:10 elapsed, ETA 0:00:05  fitted, gamma 2.20",
                          "response r0c3: 4/4 (100%), in 0:00:15  fitted, gamma 2.20"]


def test_a_log_gets_at_most_a_line_per_tenth_and_a_stage_said_done_again_once(clock):
    out = io.StringIO()
    view = ProgressView(out)
    for k in range(1001):
        view.event(Progress(stage="solve", done=k, total=1000, message="objective", value=0.5))
    view.event(Progress(stage="solve", done=1000, total=1000, message="objective", value=0.5))
    view.event(Progress(stage="gray codes", item="r0c0", done=12, total=12))
    view.event(Progress(stage="gray codes", item="r0c1", done=0, total=12))   # the next slot counts again
    view.close()
    lines = out.getvalue().splitlines()
    assert [line.split(":")[0] for line in lines] == ["solve"] * 11 + ["gray codes r0c0", "gray codes r0c1"]
    assert lines[10].startswith("solve: 1000/1000 (100%), in") and lines[-1].startswith("gray codes r0c1: 0/12 (0%)")


def test_a_view_closed_by_a_failed_job_stops_its_bars_and_draws_the_next_job(clock):
    out = Terminal()

    class Client:
        async def run_job(self, kind, params, on_event):
            on_event(Progress(stage="exposure", done=1, total=2, message="every projector white"))
            on_event("camera 0: exposure 8 ms")
            if kind == "fails":
                raise RuntimeError("camera unplugged")
            on_event(Progress(stage="exposure", done=2, total=2, message="ok"))
            return {"ok": True}

    view = ProgressView(out)
    assert view.tty
    with pytest.raises(RuntimeError, match="camera unplugged"):
        asyncio.run(run_job(Client(), "fails", {}, view=view))
    assert not live_threads(), "close() stopped the live bars"
    assert "camera 0: exposure 8 ms" in out.getvalue() and "1/2" in out.getvalue() and "\x1b[" in out.getvalue()
    assert asyncio.run(run_job(Client(), "works", {}, view=view)) == {"ok": True}
    assert not live_threads()
    assert "exposure: 2/2 (100%), in 0:00:00  ok" in out.getvalue()


def test_upload_progress_in_a_log_counts_bytes_with_speed_and_eta(clock):
    out = io.StringIO()
    p = ByteProgress("uploaded", rate=True, stream=out)
    total, start = 200_000_000, 40_000_000                 # resumed: 40 MB were already on the coordinator
    for k in range(17):
        clock.now = 1000.0 + k
        p(start + 10_000_000 * k, total, start=start)
    p.end()
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0] == "uploaded 40.0 MB / 200.0 MB (20%), 0:00:00 elapsed, ETA ?"
    assert "uploaded 100.0 MB / 200.0 MB (50%) at 10.0 MB/s, 0:00:06 elapsed, ETA 0:00:10" in lines
    assert lines[-1] == "uploaded 200.0 MB / 200.0 MB (100%) at 10.0 MB/s, in 0:00:16"
    assert len(lines) == 9                                  # 20 %, 30 %, ... 100 %


def test_small_inputs_show_no_progress(clock):
    out = io.StringIO()
    p = ByteProgress("hashed", stream=out)
    p(1000, content_format.PROGRESS_MIN_BYTES - 1)
    p.end()
    assert out.getvalue() == ""
