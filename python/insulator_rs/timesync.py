"""One clock for every stamp: another clock's time -> vehicle time, offset and drift.

A sensor or a companion computer keeps its own clock; the vehicle clock
(:attr:`insulator_rs.ports.vehicle.VehicleState.time`, PX4's boot time) is the one every
stamp must be in. The map is affine, ``vehicle = offset + (1 + drift) * other``
(crystal clocks drift by tens of ppm: 3.6 ms an hour at 1 ppm), fitted by least
squares over a sliding window of pairs and made robust by rejecting outliers (residuals
beyond ``REJECT_MAD`` median absolute deviations, iterated) before the final fit.

Two kinds of pairs:

* two-way exchanges (MAVLink TIMESYNC, as PX4's ``Timesync`` and MAVROS do): we send
  ``ts1`` = our time, the autopilot answers ``tc1`` = its time; the reply arrives at our
  ``now``. Its time is matched to the midpoint ``(ts1 + now) / 2``, the round trip bounds
  the error, and exchanges slower than ``max_rtt`` are dropped.
  :class:`TimesyncExchange` speaks the message fields (ns);
* one-way stamps (a LiDAR packet stamped by the sensor, received here): arrival =
  send time + a latency that is never negative, so the map is the lower envelope of
  the pairs (the line under all of them with the least summed latency, drift bounded).

Everything is in seconds (float64). Before the first pair the map is undefined
(:meth:`ClockMap.ready` is False); with one pair (or all pairs at one instant) drift is 0.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from insulator_rs.exceptions import TimeSyncError

#: Outlier rejection threshold, in median absolute deviations (scaled to sigma).
REJECT_MAD = 3.0
#: Floor of the rejection threshold (s): below this residuals are noise, never outliers.
REJECT_FLOOR_S = 50e-6
#: Pairs kept (the least latency of each bin) before a one-way fit's hull.
ONE_WAY_BINS = 256


@dataclass(frozen=True)
class ClockFit:
    """``target = offset + (1 + drift) * (source - source_ref) + ...`` around ``source_ref``.

    Kept relative to a reference instant so large clock values (ns since 1970) lose no
    precision. ``rms`` is the residual RMS (s) of the inliers; ``n`` how many were used.
    """

    source_ref: float
    target_ref: float
    drift: float
    rms: float
    n: int

    @property
    def offset(self) -> float:
        """``target - (1 + drift) * source`` at source 0."""
        return self.target_ref - (1.0 + self.drift) * self.source_ref

    def __call__(self, source: float | np.ndarray) -> np.ndarray:
        return self.target_ref + (1.0 + self.drift) * (np.asarray(source, np.float64) - self.source_ref)

    def inverse(self, target: float | np.ndarray) -> np.ndarray:
        return self.source_ref + (np.asarray(target, np.float64) - self.target_ref) / (1.0 + self.drift)


def robust_line(x: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> ClockFit:
    """Least-squares ``y - y0 = (1 + drift)(x - x0)`` with iterated MAD outlier rejection."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if len(x) == 0:
        raise TimeSyncError("time sync: no pairs to fit")
    w = np.ones_like(x) if weights is None else np.asarray(weights, np.float64)
    keep = np.ones(len(x), bool)
    x0, y0 = float(np.median(x)), float(np.median(y))
    for _ in range(5):
        fit = _weighted_fit(x[keep] - x0, y[keep] - y0, w[keep])
        resid = (y - y0) - (fit[0] + fit[1] * (x - x0))
        centre = float(np.median(resid[keep]))
        mad = float(np.median(np.abs(resid[keep] - centre))) * 1.4826
        new_keep = np.abs(resid - centre) <= max(REJECT_MAD * mad, REJECT_FLOOR_S)
        if new_keep.sum() < 2 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    a, b = _weighted_fit(x[keep] - x0, y[keep] - y0, w[keep])
    resid = (y[keep] - y0) - (a + b * (x[keep] - x0))
    return ClockFit(source_ref=x0, target_ref=y0 + a, drift=b - 1.0,
                    rms=float(np.sqrt(np.mean(resid**2))) if len(resid) else 0.0, n=int(keep.sum()))


def _weighted_fit(dx: np.ndarray, dy: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    if len(dx) < 2 or float(np.ptp(dx)) <= 0.0:
        return float(np.average(dy - dx, weights=w)) if len(dx) else 0.0, 1.0
    sw = w.sum()
    mx, my = (w * dx).sum() / sw, (w * dy).sum() / sw
    sxx = (w * (dx - mx) ** 2).sum()
    slope = (w * (dx - mx) * (dy - my)).sum() / sxx
    return float(my - slope * mx), float(slope)


class ClockMap:
    """A sliding-window estimate of ``target = f(source)``.

    ``window``: how many pairs are kept. ``refit_every``: pairs between refits.
    """

    def __init__(self, *, window: int = 256, refit_every: int = 8) -> None:
        if window < 2:
            raise ValueError(f"window: must be >= 2, got {window}")
        if refit_every < 1:
            raise ValueError(f"refit_every: must be >= 1, got {refit_every}")
        self.window = int(window)
        self.refit_every = int(refit_every)
        self._pairs: deque[tuple[float, float, float]] = deque(maxlen=self.window)
        self._fit: ClockFit | None = None
        self._since_fit = 0
        self.rejected = 0

    def ready(self) -> bool:
        return bool(self._pairs)

    @property
    def fit(self) -> ClockFit:
        if self._fit is None or self._since_fit > 0:
            self._fit = self._refit()
            self._since_fit = 0
        return self._fit

    def _add(self, source: float, target: float, weight: float = 1.0) -> None:
        if not (math.isfinite(source) and math.isfinite(target)):
            self.rejected += 1
            return
        self._pairs.append((float(source), float(target), float(weight)))
        self._since_fit += 1

    def _arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a = np.asarray(self._pairs, np.float64).reshape(-1, 3)
        return a[:, 0], a[:, 1], a[:, 2]

    def _refit(self) -> ClockFit:
        x, y, w = self._arrays()
        return robust_line(x, y, w)

    def to_target(self, source: float | np.ndarray) -> np.ndarray:
        """Maps source-clock times to the target clock; raises if no pair was seen."""
        if not self._pairs:
            raise TimeSyncError("time sync: no clock pairs yet")
        return self.fit(source)


class TwoWaySync(ClockMap):
    """Our clock -> the remote (vehicle) clock from request/response exchanges."""

    def __init__(self, *, window: int = 64, refit_every: int = 1, max_rtt: float = 0.05) -> None:
        super().__init__(window=window, refit_every=refit_every)
        if not (math.isfinite(max_rtt) and max_rtt > 0):
            raise ValueError(f"max_rtt: must be a finite number > 0, got {max_rtt}")
        self.max_rtt = float(max_rtt)

    def add_exchange(self, local_send: float, remote: float, local_receive: float) -> bool:
        """One exchange (s): False (and counted in ``rejected``) if its round trip is
        negative or longer than ``max_rtt``."""
        rtt = local_receive - local_send
        if not (0.0 <= rtt <= self.max_rtt):
            self.rejected += 1
            return False
        # Shorter round trips bound the midpoint error more tightly: weight 1 / rtt^2.
        self._add(0.5 * (local_send + local_receive), remote, 1.0 / max(rtt, 1e-6) ** 2)
        return True


class OneWaySync(ClockMap):
    """Sender clock -> our clock from (sender stamp, arrival) pairs: the latency envelope.

    Arrival = map(sent) + latency, latency >= 0, so the map is the line under every pair
    that hugs them closest: the lower convex hull edge (or a slope bound through a hull
    vertex) minimising the summed latencies, a linear programme whose optimum lies on the
    hull (the classic one-way clock-skew estimate). The slope is bounded to
    ``1 +- max_drift``: a single burst of pairs that all arrived at once (no span of
    arrivals to read a rate from) then yields drift 0, not a collapsed clock. Pairs are
    first reduced to the least-latency one of each of ``ONE_WAY_BINS`` bins.
    """

    def __init__(self, *, window: int = 2048, refit_every: int = 64, max_drift: float = 1e-3) -> None:
        super().__init__(window=window, refit_every=refit_every)
        if not (math.isfinite(max_drift) and 0 <= max_drift < 0.5):
            raise ValueError(f"max_drift: must be in [0, 0.5), got {max_drift}")
        self.max_drift = float(max_drift)

    def add(self, sent: float, received: float) -> None:
        self._add(sent, received)

    def _refit(self) -> ClockFit:
        x, y, _ = self._arrays()
        x0 = float(x.min())
        dx = x - x0
        d = y - x  # offset + drift * x + latency
        span = float(dx.max())
        if span > 0 and len(x) > ONE_WAY_BINS:
            bins = np.minimum((dx / span * ONE_WAY_BINS).astype(np.int64), ONE_WAY_BINS - 1)
            order = np.lexsort((d, bins))
            first = np.r_[True, bins[order][1:] != bins[order][:-1]]
            keep = order[first]
            hx, hd = dx[keep], d[keep]
        else:
            hx, hd = dx, d
        hull = _lower_hull(hx, hd)
        vx, vd = hx[hull], hd[hull]
        slopes = [0.0, -self.max_drift, self.max_drift]
        if len(vx) > 1:
            edge = np.diff(vd) / np.maximum(np.diff(vx), 1e-12)
            slopes += [float(e) for e in edge if abs(e) <= self.max_drift]
        best: tuple[float, float, float] | None = None
        for slope in slopes:
            a = float(np.min(vd - slope * vx))  # the line through the support vertex
            cost = float(np.sum(d - (a + slope * dx)))
            if best is None or cost < best[0]:
                best = (cost, a, slope)
        assert best is not None
        _, a, slope = best
        resid = d - (a + slope * dx)
        return ClockFit(source_ref=x0, target_ref=x0 + a, drift=slope, rms=float(np.sqrt(np.mean(resid**2))),
                        n=len(x))


def _lower_hull(x: np.ndarray, y: np.ndarray) -> list[int]:
    """Indices of the lower convex hull of the points, left to right (monotone chain)."""
    order = np.lexsort((y, x))
    hull: list[int] = []
    for i in order.tolist():
        while len(hull) >= 2:
            i1, i2 = hull[-2], hull[-1]
            cross = (x[i2] - x[i1]) * (y[i] - y[i1]) - (y[i2] - y[i1]) * (x[i] - x[i1])
            if cross <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    return hull


class TimesyncExchange:
    """MAVLink TIMESYNC (ns fields) on top of :class:`TwoWaySync`.

    A request is ``TIMESYNC(tc1=0, ts1=now_ns)``; the autopilot answers
    ``TIMESYNC(tc1=its_now_ns, ts1=our ts1)``. Replies to requests we did not send, and
    requests from the other side (``tc1 == 0``), are ignored.
    """

    def __init__(self, sync: TwoWaySync | None = None) -> None:
        self.sync = sync or TwoWaySync()
        self._outstanding: deque[int] = deque(maxlen=32)

    def request(self, now_ns: int) -> tuple[int, int]:
        """(tc1, ts1) of the request to send now."""
        self._outstanding.append(int(now_ns))
        return 0, int(now_ns)

    def on_message(self, tc1: int, ts1: int, now_ns: int) -> bool:
        """Feed a received TIMESYNC; True if it was an answer to one of ours and was used."""
        if tc1 == 0 or ts1 not in self._outstanding:
            return False
        self._outstanding.remove(ts1)
        return self.sync.add_exchange(ts1 * 1e-9, tc1 * 1e-9, now_ns * 1e-9)


@dataclass(frozen=True)
class ChainedClock:
    """sensor -> host -> vehicle: a :class:`OneWaySync` (sensor stamps vs host arrival)
    composed with a host -> vehicle map (TIMESYNC, or the identity when the host clock is
    already the vehicle clock, as in simulation)."""

    sensor_to_host: OneWaySync
    host_to_vehicle: ClockMap | None = None

    def __call__(self, sensor_s: float | np.ndarray) -> np.ndarray:
        host = self.sensor_to_host.to_target(sensor_s)
        return host if self.host_to_vehicle is None else self.host_to_vehicle.to_target(host)


class TelemetryClock:
    """The vehicle clock *now*, for a host that only sees the vehicle's telemetry.

    A thread polls ``vehicle_time()`` (the stamp of the newest telemetry, e.g.
    ``MavlinkVehicle.state().time``, PX4's ``time_boot_ms``) every ``poll_s`` and pairs
    each new stamp with the host clock at the poll: that pair is (send, arrival) with a
    latency >= 0, so the :class:`OneWaySync` lower envelope maps vehicle -> host, and its
    inverse gives the vehicle time of any host instant. Drivers stamp arrivals with
    :meth:`now`. With an autopilot that answers MAVLink TIMESYNC,
    :class:`TimesyncExchange` is the tighter alternative (it measures the round trip).
    """

    def __init__(self, vehicle_time: Callable[[], float], *, poll_s: float = 0.002,
                 host_clock: Callable[[], float] = time.monotonic, window: int = 2048) -> None:
        if not (math.isfinite(poll_s) and poll_s > 0):
            raise ValueError(f"poll_s: must be a finite number > 0, got {poll_s}")
        self._vehicle_time = vehicle_time
        self._host = host_clock
        self.poll_s = float(poll_s)
        self.sync = OneWaySync(window=window, refit_every=16)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last: float | None = None
        self.errors = 0

    def start(self) -> TelemetryClock:
        self._thread = threading.Thread(target=self._run, name="telemetry-clock", daemon=True)
        self._thread.start()
        return self

    def poll(self) -> None:
        """One poll (the thread calls this; tests may call it directly)."""
        try:
            stamp = float(self._vehicle_time())
        except Exception:  # a vehicle that is closing or not yet connected: try again later
            self.errors += 1
            return
        host = self._host()
        if stamp != self._last and math.isfinite(stamp):
            self._last = stamp
            with self._lock:
                self.sync.add(stamp, host)

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            self.poll()

    def ready(self) -> bool:
        return self.sync.ready()

    def now(self) -> float:
        """The vehicle time (s) of this instant; raises TimeSyncError before any stamp."""
        host = self._host()
        with self._lock:
            if not self.sync.ready():
                raise TimeSyncError("time sync: no vehicle telemetry yet")
            return float(self.sync.fit.inverse(host))

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
