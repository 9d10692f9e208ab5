"""One clock for every stamp: another clock's time -> vehicle time, offset and drift.

A sensor or a companion computer keeps its own clock; the vehicle clock
(:attr:`insulator_rs.vehicle.VehicleState.time`, PX4's boot time) is the one every
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
  the pairs: within each of ``ONE_WAY_BINS`` time bins the pair of least latency is
  kept, and the line is fitted through those.

Everything is in seconds (float64). Before the first pair the map is undefined
(:meth:`ClockMap.ready` is False); with one pair (or all pairs at one instant) drift is 0.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from insulator_rs.exceptions import TimeSyncError

#: Outlier rejection threshold, in median absolute deviations (scaled to sigma).
REJECT_MAD = 3.0
#: Floor of the rejection threshold (s): below this residuals are noise, never outliers.
REJECT_FLOOR_S = 50e-6
#: Lower-envelope bins of a one-way fit.
ONE_WAY_BINS = 16


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
    """Sender clock -> our clock from (sender stamp, arrival) pairs: the latency envelope."""

    def __init__(self, *, window: int = 2048, refit_every: int = 64) -> None:
        super().__init__(window=window, refit_every=refit_every)

    def add(self, sent: float, received: float) -> None:
        self._add(sent, received)

    def _refit(self) -> ClockFit:
        x, y, _ = self._arrays()
        if len(x) < 2 * ONE_WAY_BINS:
            i = int(np.argmin(y - x))
            return ClockFit(source_ref=float(x[i]), target_ref=float(y[i]), drift=0.0, rms=0.0, n=1)
        edges = np.linspace(x.min(), x.max(), ONE_WAY_BINS + 1)
        bins = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, ONE_WAY_BINS - 1)
        lat = y - x
        picks = [np.flatnonzero(bins == b)[np.argmin(lat[bins == b])] for b in range(ONE_WAY_BINS)
                 if np.any(bins == b)]
        return robust_line(x[picks], y[picks])


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
