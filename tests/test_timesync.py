"""Time sync: offset and drift recovered from simulated clocks, robust to outliers.

Reference: the simulated truth (a clock with a known offset and drift, latencies drawn
from a seeded distribution). Tolerances are stated per test; pymavlink's TIMESYNC
message (encode -> bytes -> decode) carries the exchange in the MAVLink test.
"""

from __future__ import annotations

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
