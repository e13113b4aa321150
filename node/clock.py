"""Node clocks: the local clock (with test hooks that make it wrong on purpose)
and the rig-clock estimator (NTP-style exchanges filtered by minimum round trip).

Times are integer nanoseconds. The *rig clock* is the coordinator's monotonic
clock; a node estimates ``rig = local + offset(local)`` with an offset that is
a straight line in local time (offset and drift), fitted over the exchanges
whose round trip was close to the best one seen (queueing delay only ever adds
to a round trip, so the fastest exchanges carry the least error).
"""
from __future__ import annotations

import ctypes
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable


class LocalClock:
    """This host's monotonic clock, optionally offset and drifting (test hooks).

    ``local = host + offset_ns + (host - anchor) * drift_ppm * 1e-6`` where
    ``host`` is ``CLOCK_MONOTONIC``. With no hooks, local time *is* host time.

    ``source`` (host time in ns) and ``sleep`` (seconds) are injectable: a test passes
    a clock it moves itself, whose ``sleep`` advances it, and nothing waits for real.
    """

    def __init__(self, *, offset_ns: int = 0, drift_ppm: float = 0.0, source: Callable[[], int] = time.monotonic_ns,
                 anchor_ns: int | None = None, sleep: Callable[[float], None] = time.sleep):
        self._source = source
        self._sleep = sleep
        self.offset_ns = int(offset_ns)
        self.drift_ppm = float(drift_ppm)
        self.drift = self.drift_ppm * 1e-6
        self._anchor = source() if anchor_ns is None else int(anchor_ns)

    @property
    def anchor_ns(self) -> int:
        """Host time at which the drift hook starts counting (shared with the presenter process)."""
        return self._anchor

    @property
    def faked(self) -> bool:
        return self.offset_ns != 0 or self.drift != 0.0

    def host_now(self) -> int:
        return self._source()

    def from_host(self, host_ns: int) -> int:
        return host_ns + self.offset_ns + int(round((host_ns - self._anchor) * self.drift))

    def to_host(self, local_ns: int) -> int:
        return int(round((local_ns - self.offset_ns + self._anchor * self.drift) / (1.0 + self.drift)))

    def now(self) -> int:
        return self.from_host(self._source())

    def sleep_until(self, local_ns: int) -> int:
        """Block until the local clock reads ``local_ns``; return the host time on waking.

        One high-resolution kernel sleep (``time.sleep`` is ``clock_nanosleep``
        on Linux): no spinning, because a dozen nodes spinning at the same
        instant on a small machine would starve each other of the very CPU
        they are waiting to swap on. See :func:`precise_timers` for the slack.
        """
        deadline = self.to_host(local_ns)
        while True:
            now = self._source()
            remaining = deadline - now
            if remaining <= 0:
                return now
            self._sleep(remaining / 1e9)


def precise_timers() -> None:
    """Ask Linux for 1 µs timer slack (default 50 µs) so sleeps end on time. Best effort."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_TIMERSLACK = 29
        libc.prctl(PR_SET_TIMERSLACK, 1000, 0, 0, 0)
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass


@dataclass(frozen=True)
class ClockSample:
    """One exchange: t0/t3 on the local clock, t1/t2 on the rig clock (ns)."""

    t0: int
    t1: int
    t2: int
    t3: int

    @property
    def rtt(self) -> int:
        return (self.t3 - self.t0) - (self.t2 - self.t1)

    @property
    def offset(self) -> float:
        return ((self.t1 - self.t0) + (self.t2 - self.t3)) / 2.0

    @property
    def midpoint(self) -> float:
        return (self.t0 + self.t3) / 2.0


#: a node fits its clock estimate over this window (at the settled rate, two dozen exchanges) ...
CLOCK_WINDOW_NS = 240_000_000_000
#: ... and exchanges at its settled rate once the fitted drift spans this long (at 4 Hz: 80 exchanges)
SETTLE_SPAN_NS = 20_000_000_000


@dataclass(frozen=True)
class ClockEstimate:
    offset_ns: float      # rig - local at ``ref_local_ns``
    drift: float          # d(offset)/d(local), dimensionless (1e-6 = 1 ppm)
    ref_local_ns: float
    best_rtt_ns: int
    samples: int
    span_ns: float = 0.0          # how long the exchanges used span (local clock)
    drift_fitted: bool = False    # False: too few or too close exchanges, drift taken as 0

    def rig_time(self, local_ns: int) -> int:
        return int(round(local_ns + self.offset_ns + self.drift * (local_ns - self.ref_local_ns)))

    def local_time(self, rig_ns: int) -> int:
        # invert rig = local + off + drift*(local - ref)
        return int(round((rig_ns - self.offset_ns + self.drift * self.ref_local_ns) / (1.0 + self.drift)))


class ClockEstimator:
    """Offset and drift of the rig clock relative to the local clock.

    Parameters
    ----------
    window_ns:
        Exchanges older than this are forgotten (drift is fitted over the window).
    rtt_slack:
        A bucket's fastest exchange is used if its round trip is within ``best * (1 + rtt_slack) + rtt_margin_ns``; weights fall with the excess round trip.
    bucket_ns:
        The window is cut into buckets this long; each contributes its fastest exchange.
    min_drift_span_ns:
        Drift is fitted only once the used exchanges span at least this long.
    """

    def __init__(self, *, window_ns: int = 30_000_000_000, rtt_slack: float = 0.5, min_drift_span_ns: int = 2_000_000_000,
                 max_samples: int = 512, bucket_ns: int = 1_000_000_000, rtt_margin_ns: int = 5_000_000):
        self.bucket_ns = bucket_ns
        self.rtt_margin_ns = rtt_margin_ns
        self.window_ns = window_ns
        self.rtt_slack = rtt_slack
        self.min_drift_span_ns = min_drift_span_ns
        self._samples: deque[ClockSample] = deque(maxlen=max_samples)
        self._lock = threading.Lock()
        self._estimate: ClockEstimate | None = None

    def reset(self) -> None:
        with self._lock:
            self._samples.clear()
            self._estimate = None

    def add(self, sample: ClockSample) -> ClockEstimate | None:
        if sample.rtt < 0 or sample.t3 < sample.t0:
            return self._estimate  # impossible exchange (clock stepped?): ignore it
        with self._lock:
            self._samples.append(sample)
            horizon = sample.t3 - self.window_ns
            while self._samples and self._samples[0].t3 < horizon:
                self._samples.popleft()
            self._estimate = self._fit(list(self._samples))
            return self._estimate

    @property
    def estimate(self) -> ClockEstimate | None:
        return self._estimate

    def _fit(self, samples: list[ClockSample]) -> ClockEstimate | None:
        # plain Python over at most ``max_samples`` exchanges (a few hundred, well under a millisecond):
        # the node process, which runs this, imports no numpy (6-7 MB of its memory)
        if not samples:
            return None
        rtts = [float(s.rtt) for s in samples]
        mids = [s.midpoint for s in samples]
        offs = [s.offset for s in samples]
        best = min(rtts)
        # The fastest exchange of each time bucket: spread over the window for the drift,
        # each as free of queueing delay as that moment allowed (ties: the earliest exchange).
        start = min(mids)
        fastest: dict[int, int] = {}
        for i, (mid, rtt) in enumerate(zip(mids, rtts)):
            b = math.floor((mid - start) / self.bucket_ns)
            j = fastest.get(b)
            if j is None or rtt < rtts[j]:
                fastest[b] = i
        limit = best * (1.0 + self.rtt_slack) + self.rtt_margin_ns
        keep = [fastest[b] for b in sorted(fastest) if rtts[fastest[b]] <= limit]
        m = [mids[i] for i in keep]
        o = [offs[i] for i in keep]
        # an exchange's error bound grows with its excess round trip
        w = [1.0 / (rtts[i] - best + max(best, 100_000.0)) for i in keep]
        ref = mids[-1]
        span = max(m) - min(m) if m else 0.0
        fitted = len(m) >= 4 and span >= self.min_drift_span_ns
        if fitted:
            x = [v - ref for v in m]
            sw = math.fsum(w)
            xm = math.fsum(wi * xi for wi, xi in zip(w, x)) / sw
            ym = math.fsum(wi * oi for wi, oi in zip(w, o)) / sw
            var = math.fsum(wi * (xi - xm) ** 2 for wi, xi in zip(w, x))
            cov = math.fsum(wi * (xi - xm) * (oi - ym) for wi, xi, oi in zip(w, x, o))
            drift = cov / var if var > 0 else 0.0
            offset = ym - drift * xm
        else:
            # too short for a drift: the single fastest exchange is the best offset we have
            i = rtts.index(best)
            drift, offset, ref = 0.0, offs[i], mids[i]
        if not math.isfinite(offset) or not math.isfinite(drift):
            return self._estimate
        return ClockEstimate(offset_ns=offset, drift=drift, ref_local_ns=ref, best_rtt_ns=int(best), samples=len(keep),
                             span_ns=span, drift_fitted=fitted)
