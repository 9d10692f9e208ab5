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
from typing import Any
from dataclasses import dataclass

import numpy as np

from insulator_rs.exceptions import TimeSyncError

#: Outlier rejection threshold, in median absolute deviations (scaled to sigma).
REJECT_MAD = 3.0
#: Floor of the rejection threshold (s): below this residuals are noise, never outliers.
REJECT_FLOOR_S = 50e-6
#: :class:`TelemetryClock`: the least-latency pair of each this many s of vehicle time ...
TELEMETRY_BIN_S = 0.01
#: ... and this many of them (3 s): a window that follows the vehicle clock's rate (see there).
TELEMETRY_WINDOW = 300
#: :class:`TelemetryClock`: the vehicle clock's rate may differ from the host's by this much.
TELEMETRY_MAX_RATE_ERROR = 0.9
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


#: exchanges whose prediction error is kept (TwoWaySync.prediction_errors): minutes of TIMESYNC
PREDICTION_ERRORS_KEPT = 4096


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
        # refit once ``refit_every`` pairs came (a fit per pair was most of the SITL sensor
        # head's time: it maps every datagram's stamp)
        if self._fit is None or self._since_fit >= self.refit_every:
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
        # s: each accepted exchange's remote time less what the map said before it came. A
        # crystal is a line, so these stay at the round trip's size; a clock whose rate wanders
        # (PX4 SITL's lockstep on a starved box) shows here as the map's real error.
        self.prediction_errors: deque[float] = deque(maxlen=PREDICTION_ERRORS_KEPT)

    def prediction_error_ms(self) -> dict[str, float] | None:
        """The map's error on the exchanges it had not seen yet (ms, absolute): median, 99th
        percentile, worst; None before two exchanges."""
        if not self.prediction_errors:
            return None
        e = np.abs(np.asarray(self.prediction_errors)) * 1e3
        return {"p50": round(float(np.median(e)), 3), "p99": round(float(np.percentile(e, 99)), 3),
                "max": round(float(e.max()), 3)}

    def add_exchange(self, local_send: float, remote: float, local_receive: float) -> bool:
        """One exchange (s): False (and counted in ``rejected``) if its round trip is
        negative or longer than ``max_rtt``."""
        rtt = local_receive - local_send
        if not (0.0 <= rtt <= self.max_rtt):
            self.rejected += 1
            return False
        mid = 0.5 * (local_send + local_receive)
        if len(self._pairs) >= 2 and math.isfinite(mid) and math.isfinite(remote):
            self.prediction_errors.append(remote - float(self.to_target(mid)))
        # Shorter round trips bound the midpoint error more tightly: weight 1 / rtt^2.
        self._add(mid, remote, 1.0 / max(rtt, 1e-6) ** 2)
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

    ``bin_s``: keep only the least-latency pair of each ``bin_s`` of sender time (then
    ``window`` counts bins, not pairs). The drift is read from the span of the window: the
    latency floor's jitter divided by the span. A window of pairs at a sensor's packet rate
    spans seconds (the Mid-360 driver's 2048 pairs: 16 s), where a floor that moves by a few
    ms (a loaded computer) reads as +-1000 ppm: measured against PX4 SITL, -692 and +856 ppm
    for a truth of -25. Bins of 0.25 s x 2048 span 8.5 minutes.
    """

    def __init__(self, *, window: int = 2048, refit_every: int = 64, max_drift: float = 1e-3,
                 bin_s: float | None = None) -> None:
        super().__init__(window=window, refit_every=refit_every)
        if not (math.isfinite(max_drift) and 0 <= max_drift < 1.0):
            raise ValueError(f"max_drift: must be in [0, 1), got {max_drift}")
        if bin_s is not None and not (math.isfinite(bin_s) and bin_s > 0):
            raise ValueError(f"bin_s: must be a finite number > 0 or None, got {bin_s}")
        self.max_drift = float(max_drift)
        self.bin_s = None if bin_s is None else float(bin_s)
        self._bin: int | None = None  # the sender-time bin of the newest pair kept

    def add(self, sent: float, received: float) -> None:
        if self.bin_s is None or not (math.isfinite(sent) and math.isfinite(received)):
            self._add(sent, received)
            return
        b = math.floor(sent / self.bin_s)
        if self._bin is not None and b <= self._bin and self._pairs:
            # the newest bin (or, out of order, an older one: kept in the newest, conservatively)
            s0, r0, _ = self._pairs[-1]
            if received - sent < r0 - s0:
                self._pairs[-1] = (float(sent), float(received), 1.0)
                self._since_fit += 1
            return
        self._bin = b
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


class RateTrackingSync(OneWaySync):
    """A one-way map whose rate is free: a vehicle clock that need not run at the host's rate
    (:class:`TelemetryClock`). The hull's edge over the window's middle (the envelope
    programme) reads its rate from whichever two pairs span the middle, a few ms apart when the
    window is short: with 1 ms stamps that is a rate off by 10 %. So the rate is the robust
    least-squares slope of the window's least-latency pairs (the bins: latency jitter
    averages out over the span), and the line is then lowered onto the envelope (the pair
    with the least latency). Before ``min_span_s`` of pairs the rate is the host's.
    """

    def __init__(self, *, window: int, bin_s: float, max_drift: float, min_span_s: float = 1.0,
                 refit_every: int = 16) -> None:
        super().__init__(window=window, refit_every=refit_every, max_drift=max_drift, bin_s=bin_s)
        if not (math.isfinite(min_span_s) and min_span_s > 0):
            raise ValueError(f"min_span_s: must be a finite number > 0, got {min_span_s}")
        self.min_span_s = float(min_span_s)

    def _refit(self) -> ClockFit:
        x, y, _ = self._arrays()
        x0 = float(x.min())
        dx, d = x - x0, y - x  # d = offset + drift * dx + latency
        slope = 0.0
        if float(dx.max()) >= self.min_span_s:
            line = robust_line(dx, d + dx)  # its drift is d's slope
            slope = float(np.clip(line.drift, -self.max_drift, self.max_drift))
        a = float(np.min(d - slope * dx))  # onto the envelope
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

    The window is short (the least-latency pair of each 10 ms, 3 s of them) and the rate free
    (+-90 %), because the vehicle clock need not run at the host's rate: PX4 SITL runs in
    lockstep, ``-s 2`` twice as fast, and slower whenever a loaded box starves it. Measured
    against PX4 SITL at ``-s 1`` with other jobs beside it: PX4's clock fell 1.7 s behind the
    host's in 20 s (-8.5 %). The long, +-1000 ppm window this had (2048 pairs) could not follow:
    the live drivers' stamps then drifted from the poses by up to seconds (LiDAR scans 5.7 s off
    in a recording) and the pairing of frames with points collapsed. A real autopilot's crystal
    costs this nothing: 3 s of 1 ms stamps still carry the map to a millisecond.
    """

    def __init__(self, vehicle_time: Callable[[], float], *, poll_s: float = 0.002,
                 host_clock: Callable[[], float] = time.monotonic, window: int = TELEMETRY_WINDOW) -> None:
        if not (math.isfinite(poll_s) and poll_s > 0):
            raise ValueError(f"poll_s: must be a finite number > 0, got {poll_s}")
        self._vehicle_time = vehicle_time
        self._host = host_clock
        self.poll_s = float(poll_s)
        self.sync = RateTrackingSync(window=window, bin_s=TELEMETRY_BIN_S, max_drift=TELEMETRY_MAX_RATE_ERROR)
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

    def to_host(self, vehicle: float | np.ndarray) -> np.ndarray:
        """The host-clock instants of vehicle times; raises TimeSyncError before any stamp."""
        with self._lock:
            if not self.sync.ready():
                raise TimeSyncError("time sync: no vehicle telemetry yet")
            return np.asarray(self.sync.fit(vehicle), np.float64)

    def host_now(self) -> float:
        """The host clock this maps from (``time.monotonic`` unless told)."""
        return self._host()

    def to_vehicle(self, host: float | np.ndarray) -> np.ndarray:
        """The vehicle times of host-clock instants (a driver stamping arrivals on the host's
        clock maps them through this); raises TimeSyncError before any stamp."""
        with self._lock:
            if not self.sync.ready():
                raise TimeSyncError("time sync: no vehicle telemetry yet")
            return np.asarray(self.sync.fit.inverse(host), np.float64)

    def record(self) -> TimesyncRecord:
        """Source ``telemetry`` with the map host -> vehicle (the envelope's inverse), or
        ``none`` before any stamp."""
        with self._lock:
            if not self.sync.ready():
                return TimesyncRecord()
            fit = self.sync.fit  # vehicle -> host
        return TimesyncRecord(source="telemetry", offset_s=float(fit.inverse(0.0)),
                              drift_ppm=(1.0 / (1.0 + fit.drift) - 1.0) * 1e6, exchanges=fit.n)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)


#: ``TimesyncRecord.source`` values: the two-way TIMESYNC map, the telemetry-stamp fallback, none.
CLOCK_SOURCES = ("timesync", "telemetry", "none")


@dataclass(frozen=True)
class TimesyncRecord:
    """How the companion computer knew vehicle time (the summary's ``timesync``).

    ``source``: ``timesync`` (MAVLink TIMESYNC, two-way), ``telemetry`` (the autopilot never
    answered TIMESYNC: :class:`TelemetryClock`'s envelope of telemetry stamps stood in) or
    ``none`` (no host-to-vehicle map: the vehicle clock was the host's own, or nothing was
    fitted). ``offset_s`` and ``drift_ppm``: ``vehicle = offset + (1 + drift) * host``;
    ``rtt_ms``: the median round trip; ``exchanges``: pairs used; ``rejected``: messages or
    pairs refused (foreign, malformed, too slow)."""

    source: str = "none"
    offset_s: float | None = None
    drift_ppm: float | None = None
    rtt_ms: float | None = None
    exchanges: int = 0
    rejected: int = 0
    # the two-way map's residual on each exchange before it was fitted (ms: p50, p99, max), None
    # where no two-way map ran (TwoWaySync.prediction_error_ms)
    map_residual_ms: dict[str, float] | None = None


class VehicleClock:
    """The vehicle time *now* for the companion's drivers: the two-way map (``two_way``: the
    MAVLink client's TIMESYNC, anything with ``ready()``, ``now()`` and ``record()``) once it
    is ready, and ``fallback`` (a :class:`TelemetryClock`) while it is not, e.g. an autopilot
    that never answers TIMESYNC. Once the two-way map was used it stays in use (no jump back
    and forth between two estimates)."""

    def __init__(self, two_way: Any, fallback: TelemetryClock) -> None:
        self.two_way = two_way
        self.fallback = fallback
        self._use_two_way = False

    @property
    def errors(self) -> int:
        return self.fallback.errors

    def start(self) -> VehicleClock:
        self.fallback.start()
        return self

    def _two_way_in_use(self) -> bool:
        if self.two_way is not None and (self._use_two_way or self.two_way.ready()):
            self._use_two_way = True
        return self._use_two_way

    def now(self) -> float:
        return float(self.two_way.now()) if self._two_way_in_use() else self.fallback.now()

    def host_now(self) -> float:
        """The host clock both maps read (``time.monotonic``)."""
        return self.fallback.host_now()

    def to_vehicle(self, host: float | np.ndarray) -> np.ndarray:
        """The vehicle times of host instants, by the map :meth:`now` uses."""
        if self._two_way_in_use():
            return np.asarray(self.two_way.to_vehicle(host), np.float64)
        return self.fallback.to_vehicle(host)

    def record(self) -> TimesyncRecord:
        """The two-way map's record once used; else the fallback's (source ``telemetry``)."""
        if self.two_way is not None and (self._use_two_way or self.two_way.ready()):
            return self.two_way.record()
        record = self.fallback.record()
        if self.two_way is None:
            return record
        return TimesyncRecord(record.source, record.offset_s, record.drift_ppm, None, record.exchanges,
                              int(self.two_way.record().rejected))

    def close(self) -> None:
        self.fallback.close()
