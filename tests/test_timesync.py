"""Time sync: offset and drift recovered from simulated clocks, robust to outliers.

Reference: the simulated truth (a clock with a known offset and drift, latencies drawn
from a seeded distribution). Tolerances are stated per test; pymavlink's TIMESYNC
message (encode -> bytes -> decode) carries the exchange in the MAVLink test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from insulator_rs.exceptions import TimeSyncError
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.timesync import (
    ChainedClock,
    ClockMap,
    OneWaySync,
    TelemetryClock,
    TimesyncExchange,
    TwoWaySync,
    robust_line,
)

OFFSET = 1234.5678  # s: the remote clock is far ahead
DRIFT = 40e-6  # 40 ppm


def remote(t: np.ndarray | float) -> np.ndarray:
    return OFFSET + (1.0 + DRIFT) * np.asarray(t, np.float64)


def test_two_way_exchanges_recover_offset_and_drift_despite_outliers() -> None:
    """Symmetric delays 1-5 ms, 10 % of replies delayed 20-40 ms on the way back (and
    kept: under max_rtt). Tolerance: 0.2 ms in time over the window, 2 ppm in drift."""
    rng = np.random.default_rng(1)
    sync = TwoWaySync(window=200, max_rtt=0.05)
    for k in range(200):
        send = 10.0 + 0.1 * k
        up, down = rng.uniform(0.001, 0.005, 2)
        if rng.random() < 0.1:
            down += rng.uniform(0.02, 0.04)
        assert sync.add_exchange(send, float(remote(send + up)), send + up + down)
    fit = sync.fit
    assert fit.drift == pytest.approx(DRIFT, abs=2e-6)
    t = np.array([10.0, 20.0, 29.9])
    assert np.max(np.abs(sync.to_target(t) - remote(t))) < 2e-4


def _exchanges(sync: TwoWaySync, clock, seconds: float = 60.0, rate_hz: float = 10.0) -> None:
    rng = np.random.default_rng(3)
    for k in range(int(seconds * rate_hz)):
        send = 10.0 + k / rate_hz
        up, down = rng.uniform(0.0002, 0.001, 2)
        sync.add_exchange(send, float(clock(send + up)), send + up + down)


def test_the_map_reports_its_own_error_on_each_new_exchange() -> None:
    """A crystal (offset + 40 ppm) is a line: the map predicts each new exchange within the
    round trip's asymmetry (< 1 ms). A clock whose rate drops 20 % at t = 40 s (PX4 SITL's
    lockstep starved) is not: one second after the step the remote time is 0.2 s behind the
    line the window held, so the worst prediction error is tens of ms at least. Reference:
    the simulated clocks themselves."""
    crystal = TwoWaySync(window=64)
    _exchanges(crystal, remote)
    e = crystal.prediction_error_ms()
    assert e is not None and e["p99"] < 1.0 and e["max"] < 1.0

    def slowed(t):
        t = np.asarray(t, np.float64)
        return OFFSET + np.where(t < 40.0, t, 40.0 + 0.8 * (t - 40.0))

    wandering = TwoWaySync(window=64)
    _exchanges(wandering, slowed)
    e = wandering.prediction_error_ms()
    assert e is not None and e["max"] > 20.0 and e["p50"] < 5.0
    assert TwoWaySync().prediction_error_ms() is None


def test_two_way_rejects_slow_or_impossible_round_trips() -> None:
    sync = TwoWaySync(max_rtt=0.01)
    assert not sync.add_exchange(1.0, 5.0, 1.5)
    assert not sync.add_exchange(1.0, 5.0, 0.9)
    assert sync.rejected == 2
    assert not sync.ready()
    with pytest.raises(TimeSyncError, match="no clock pairs"):
        sync.to_target(1.0)


def test_one_way_lower_envelope_tracks_offset_and_drift() -> None:
    """Packets stamped by a sensor clock, received with 0.2 ms + exponential(2 ms)
    latency and 5 % stalls of 30-80 ms. The envelope fit must land within 0.5 ms of the
    true map (the minimum latency is 0.2 ms) and within 5 ppm of the drift."""
    rng = np.random.default_rng(2)
    sync = OneWaySync(window=4000, refit_every=100)
    sensor = np.arange(0.0, 20.0, 0.005)  # 200 packets/s
    vehicle = (sensor - OFFSET) / (1.0 + DRIFT)  # sensor = remote(vehicle)
    latency = 0.0002 + rng.exponential(0.002, len(sensor))
    stall = rng.random(len(sensor)) < 0.05
    latency[stall] += rng.uniform(0.03, 0.08, stall.sum())
    for s, v in zip(sensor, vehicle + latency):
        sync.add(float(s), float(v))
    got = sync.to_target(sensor)
    assert np.max(np.abs(got - vehicle)) < 5e-4
    assert sync.fit.drift == pytest.approx(1.0 / (1.0 + DRIFT) - 1.0, abs=5e-6)


def _loaded_link(rng: np.random.Generator, seconds: float, rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sensor stamps, true vehicle times, arrivals) of a link on a loaded computer: 0.1 ms +
    exponential(1 ms) latency, and the floor itself raised by 2-30 ms for 1-8 s stretches
    about a third of the time (the receive thread starved), as measured against PX4 SITL."""
    sensor = np.arange(0.0, seconds, 1.0 / rate)
    vehicle = (sensor - OFFSET) / (1.0 + DRIFT)
    latency = 0.0001 + rng.exponential(0.001, len(sensor))
    t = 0.0
    while t < seconds:
        length = rng.uniform(1.0, 8.0)
        if rng.random() < 0.35:
            latency[(sensor >= t) & (sensor < t + length)] += rng.uniform(0.002, 0.03)
        t += length
    return sensor, vehicle, vehicle + latency


def test_one_way_drift_over_a_loaded_link_needs_a_long_window() -> None:
    """Reference: the true map. Five minutes of a Mid-360's pairs (125 a second) over a loaded
    link: the binned window (the least-latency pair of each 0.25 s, 8.5 minutes) reads the drift
    within 5 ppm (issue 18's target); a window of the last 2048 pairs (16 s, as the driver kept
    before) cannot (printed beside it)."""
    rng = np.random.default_rng(7)
    sensor, vehicle, arrival = _loaded_link(rng, 300.0, 125.0)
    binned, pairs = OneWaySync(bin_s=0.25), OneWaySync()
    for s, a in zip(sensor, arrival):
        binned.add(float(s), float(a))
        pairs.add(float(s), float(a))
    truth = 1.0 / (1.0 + DRIFT) - 1.0
    err_binned, err_pairs = abs(binned.fit.drift - truth) * 1e6, abs(pairs.fit.drift - truth) * 1e6
    print(f"drift error over a loaded link: binned {err_binned:.2f} ppm, last 2048 pairs {err_pairs:.1f} ppm")
    assert err_binned < 5.0
    assert err_pairs > err_binned
    assert np.max(np.abs(binned.to_target(sensor[-5000:]) - vehicle[-5000:])) < 1e-3  # the last 40 s within 1 ms


def test_one_way_bins_keep_the_least_latency_pair() -> None:
    sync = OneWaySync(bin_s=1.0)
    for sent, received in ((0.1, 0.5), (0.2, 0.25), (0.9, 1.4), (1.5, 1.6), (1.7, 1.9)):
        sync.add(sent, received)
    assert list(sync._pairs) == [(0.2, 0.25, 1.0), (1.5, 1.6, 1.0)]
    with pytest.raises(ValueError, match="bin_s"):
        OneWaySync(bin_s=0.0)


def test_robust_line_ignores_gross_outliers() -> None:
    x = np.linspace(0, 100, 101)
    y = 3.0 + (1 + 1e-4) * x
    y[::10] += 5.0
    fit = robust_line(x, y)
    assert fit.drift == pytest.approx(1e-4, abs=1e-9)
    assert fit.offset == pytest.approx(3.0, abs=1e-6)
    assert fit.n == 90


def test_single_pair_means_offset_only() -> None:
    m = ClockMap()
    m._add(5.0, 105.0)
    assert float(m.to_target(6.0)) == pytest.approx(106.0)


def test_timesync_messages_through_pymavlink() -> None:
    """TIMESYNC request/reply as pymavlink encodes and decodes them; the autopilot clock
    runs at OFFSET + (1 + DRIFT) t. Tolerance: 0.1 ms."""
    ex = TimesyncExchange(TwoWaySync(window=50))
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    for k in range(50):
        t_send = 100.0 + 0.2 * k
        tc1, ts1 = ex.request(int(t_send * 1e9))
        request = mav.timesync_encode(tc1, ts1)
        buf = request.pack(mav)
        got = mavlink2.MAVLink(None).decode(bytearray(buf))
        assert got.tc1 == 0
        # The autopilot answers with its clock 2 ms later; we receive it 4 ms after sending.
        reply = mav.timesync_encode(int(remote(t_send + 0.002) * 1e9), got.ts1)
        back = mavlink2.MAVLink(None).decode(bytearray(reply.pack(mav)))
        assert ex.on_message(back.tc1, back.ts1, int((t_send + 0.004) * 1e9))
    assert not ex.on_message(123, 999, 0)  # not ours
    assert not ex.on_message(0, 5, 0)  # a request from the other side
    t = np.array([100.0, 105.0])
    assert np.max(np.abs(ex.sync.to_target(t) - remote(t))) < 1e-4


def test_chained_clock_composes_sensor_host_vehicle() -> None:
    s2h = OneWaySync()
    for s in np.linspace(0, 1, 100):
        s2h.add(float(s), float(s) + 10.0)
    h2v = TwoWaySync()
    for h in (10.0, 11.0):
        h2v.add_exchange(h, h + 100.0, h)
    clock = ChainedClock(s2h, h2v)
    assert float(clock(0.5)) == pytest.approx(110.5, abs=1e-9)


def test_telemetry_clock_follows_a_simulated_autopilot() -> None:
    """Telemetry stamped every 20 ms of a vehicle clock (offset 50 s, +80 ppm), seen by
    the host 1-6 ms later; the clock's now() must be within 1.5 ms of the truth."""
    rng = np.random.default_rng(3)
    host = {"t": 0.0}
    vehicle_t = lambda h: 50.0 + (1 + 80e-6) * h  # noqa: E731
    stamps: list[float] = []

    def newest_stamp() -> float:
        return stamps[-1]

    clock = TelemetryClock(newest_stamp, host_clock=lambda: host["t"])
    with pytest.raises(TimeSyncError):
        clock.now()
    for k in range(1000):
        send_h = 0.02 * k
        stamps.append(float(vehicle_t(send_h)))
        host["t"] = send_h + rng.uniform(0.001, 0.006)
        clock.poll()
        clock.poll()  # the same stamp twice is one pair
    assert clock.sync.fit.n <= 1000
    for h in (5.0, 12.3, 19.99):
        host["t"] = h
        assert abs(clock.now() - vehicle_t(h)) < 1.5e-3


def test_telemetry_clock_against_the_simulated_px4() -> None:
    """The simulated PX4 on loopback (time_scale 1): now() within 20 ms of its clock."""
    import time as _time

    from insulator_rs.sim.px4 import start_simulated_px4

    sim, vehicle = start_simulated_px4(time_scale=1.0)
    clock = TelemetryClock(lambda: vehicle.state().time).start()
    try:
        deadline = _time.monotonic() + 5.0
        while (not clock.ready() or clock.sync.fit.n < 20) and _time.monotonic() < deadline:
            _time.sleep(0.05)
        _time.sleep(1.0)
        errors = []
        for _ in range(5):
            with sim._lock:
                truth = sim.vehicle.clock.now
                ours = clock.now()
            errors.append(abs(ours - truth))
            _time.sleep(0.1)
    finally:
        clock.close()
        vehicle.close()
    assert max(errors) < 0.02, errors


@pytest.mark.parametrize("rate", [0.915, 1.0, 2.0, 4.0])
def test_telemetry_clock_follows_a_vehicle_clock_at_another_rate(rate: float) -> None:
    """Reference: the true vehicle clock. PX4 SITL in lockstep runs at its speed factor, and
    slower when starved (measured: 0.915 of the host's rate with other jobs beside it; -s 2 and
    -s 4 run 2 and 4 times faster). Telemetry stamped in whole ms, 100 a second, arriving 0.1 ms
    + exponential(1 ms) late, and the rate stepping by 5 % halfway: 3.5 s into each rate the
    clock.s ``now`` is within 3 ms (of vehicle time) of the truth."""
    rng = np.random.default_rng(11)
    host = {"t": 0.0}
    sent: list[tuple[float, float]] = []  # (host arrival, vehicle stamp)

    def vehicle_at(h: float) -> float:
        return 50.0 + rate * h if h < 10.0 else 50.0 + rate * 10.0 + 1.05 * rate * (h - 10.0)

    stamp = {"v": float("nan")}
    clock = TelemetryClock(lambda: stamp["v"], host_clock=lambda: host["t"])
    errors = []
    for k in range(2000):  # 20 s of host time, a telemetry message every 10 ms
        t_sent = 0.01 * k
        arrival = t_sent + 1e-4 + rng.exponential(1e-3)
        host["t"] = arrival
        stamp["v"] = math.floor(vehicle_at(t_sent) * 1e3) / 1e3  # time_boot_ms
        clock.poll()
        if (3.5 < arrival < 10.0) or arrival > 13.5:
            errors.append(clock.now() - vehicle_at(arrival))
        sent.append((arrival, stamp["v"]))
    errors = np.abs(np.array(errors))
    print(f"rate {rate}: |now - truth| p50 {np.median(errors) * 1e3:.2f} ms, max {errors.max() * 1e3:.2f} ms")
    assert errors.max() < 3e-3
