"""MAVLink TIMESYNC on the companion computer: two-way, as PX4 and MAVROS do it.

Both ends ask and both answer (PX4 v1.16's ``MavlinkTimesync``, measured on its SITL):

* we ask ``TIMESYNC(tc1=0, ts1=our monotonic ns)``; PX4 answers ``tc1`` = its boot time in ns
  (``hrt_absolute_time() * 1000``, the clock of ``time_boot_ms``), ``ts1`` = our ``ts1``. The
  pair feeds :class:`insulator_rs.timesync.TimesyncExchange` (midpoint of the round trip,
  weighted by 1/RTT^2, outliers rejected), whose fit maps host time to vehicle time;
* PX4 asks us the same at 10 Hz on an onboard link (``tc1 = 0``, ``ts1`` = its ns); we answer
  ``tc1`` = our monotonic ns, ``ts1`` = its ``ts1``, so its own estimate of our clock (what it
  logs and uses for the companion's stamped messages) has its pairs too.

Requests go at :data:`REQUEST_HZ` (10 Hz, PX4's and MAVROS's rate) for the whole flight, and the
fit keeps the last :data:`WINDOW` exchanges (3.2 s): the map then follows a vehicle clock whose
rate moves. PX4 SITL runs in lockstep and slows when a loaded box starves it (measured: 0.915
to 0.98 of the host's rate); dropping to 1 Hz over a 64-exchange minute (tried first) left the
map 0.17-0.20 s ahead of the simulated PX4's clock on a loaded box. A real autopilot's crystal
loses nothing to the short window: 32 round trips of under a millisecond carry the map to
tens of microseconds. A lost, garbled or foreign TIMESYNC (an answer
to nobody's request, a negative stamp, a round trip over ``max_rtt``) is counted in
``rejected`` and changes nothing; nothing here raises on what arrives.

Vehicle time in seconds is ``time_boot_ms / 1000``: the same clock as PX4's ``tc1``, so
:meth:`MavlinkTimesync.now` is the vehicle time of this host instant.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from insulator_rs.exceptions import TimeSyncError
from insulator_rs.timesync import TimesyncExchange, TimesyncRecord, TwoWaySync

#: Request rate (Hz of host time).
REQUEST_HZ = 10.0
#: Exchanges the fit keeps (3.2 s at REQUEST_HZ).
WINDOW = 32
#: Accepted exchanges before :meth:`MavlinkTimesync.ready` (a fit on one pair has no drift).
READY_EXCHANGES = 5
#: Round trips kept for the reported median.
RTT_KEPT = 256


class MavlinkTimesync:
    """The companion's side of TIMESYNC (module docstring). Thread-safe; ``host_ns`` is our
    clock (monotonic ns). ``max_rtt`` (s): slower exchanges are rejected."""

    def __init__(self, *, host_ns: Callable[[], int] = time.monotonic_ns, max_rtt: float = 0.05) -> None:
        self._host_ns = host_ns
        self._exchange = TimesyncExchange(TwoWaySync(window=WINDOW, max_rtt=max_rtt))
        self._lock = threading.Lock()
        self._rtts: deque[float] = deque(maxlen=RTT_KEPT)
        self._next_request_ns = 0
        self.exchanges = 0  # answers to our requests that were used
        self.rejected = 0  # TIMESYNCs that were not: foreign answers, bad stamps, slow round trips
        self.answered = 0  # the autopilot's requests we answered

    # -- what the link sends -------------------------------------------------------------------
    def request_due(self) -> tuple[int, int] | None:
        """(tc1, ts1) of a request to send now, or None before the next one is due."""
        now = int(self._host_ns())
        with self._lock:
            if now < self._next_request_ns:
                return None
            self._next_request_ns = now + int(1e9 / REQUEST_HZ)
            return self._exchange.request(now)

    def on_timesync(self, tc1: object, ts1: object) -> tuple[int, int] | None:
        """A received TIMESYNC: a request of the autopilot's gets its answer (tc1, ts1) back to
        send; an answer to ours is fed to the fit; anything else is counted and dropped."""
        now = int(self._host_ns())
        if not (isinstance(tc1, int) and isinstance(ts1, int)) or tc1 < 0 or ts1 <= 0:
            with self._lock:
                self.rejected += 1
            return None
        with self._lock:
            if tc1 == 0:  # the autopilot's request: our time, its ts1
                self.answered += 1
                return now, ts1
            if self._exchange.on_message(tc1, ts1, now):
                self.exchanges += 1
                self._rtts.append((now - ts1) * 1e-9)
            else:
                self.rejected += 1
        return None

    # -- the map --------------------------------------------------------------------------------
    def ready(self) -> bool:
        with self._lock:
            return self.exchanges >= READY_EXCHANGES

    def now(self) -> float:
        """The vehicle time (s, ``time_boot_ms`` / 1000) of this instant; TimeSyncError before
        :meth:`ready`."""
        host = int(self._host_ns()) * 1e-9
        with self._lock:
            if self.exchanges < READY_EXCHANGES:
                raise TimeSyncError(f"time sync: {self.exchanges} TIMESYNC exchanges with the autopilot, "
                                    f"{READY_EXCHANGES} needed")
            return float(self._exchange.sync.to_target(host))

    def to_vehicle(self, host: float | np.ndarray) -> np.ndarray:
        """The vehicle times of host instants (s of ``host_ns``); TimeSyncError before :meth:`ready`."""
        with self._lock:
            if self.exchanges < READY_EXCHANGES:
                raise TimeSyncError(f"time sync: {self.exchanges} TIMESYNC exchanges with the autopilot, "
                                    f"{READY_EXCHANGES} needed")
            return np.asarray(self._exchange.sync.to_target(host), np.float64)

    def record(self) -> TimesyncRecord:
        """What the summary reports: source ``timesync`` once ready, else ``none``."""
        with self._lock:
            ready = self.exchanges >= READY_EXCHANGES
            fit = self._exchange.sync.fit if ready else None
            rtt = float(np.median(self._rtts)) * 1e3 if self._rtts else None
            return TimesyncRecord(source="timesync" if ready else "none",
                                  offset_s=None if fit is None else fit.offset,
                                  drift_ppm=None if fit is None else fit.drift * 1e6,
                                  rtt_ms=rtt, exchanges=self.exchanges,
                                  rejected=self.rejected, map_residual_ms=self._exchange.sync.prediction_error_ms())
