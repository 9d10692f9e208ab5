"""The Mid-360 driver while Python threads hold the GIL, as a flight loop busy with detection and
planning does on a loaded Jetson.

Reference: a Mid-360 played in real time by a process of its own (``livox_realtime_sender.py``),
on a sensor clock whose drift against the host clock is known (+25 ppm: the map sensor -> host
then has a slope of 1 - 25e-6, reported as -25 ppm). Two threads spin pure-Python loops beside
the driver for the whole stream.

What must hold whatever the machine's load: every datagram the sender sent is processed (none
lost, none left unread), every 100 ms window becomes a scan, and the sensor -> host map fitted
from the arrival stamps puts every instant of the stream within 20 ms of the truth (a fifth of
the pairing window: a frame still finds its points). The drift the fit reads is printed: on the
2-core dev box, -26.2 / -28.3 / -25.6 ppm (quiet / two spinning threads / the same beside a CI
run) against -25; at a load of 11 (a CI run, a PX4 SITL flight and this test on two cores) the
sender's and readers' starts were late enough that 8 s of data read -1000 ppm (8 ms over the
span, inside the bound). The driver this replaced (a Python ``recvfrom`` per datagram) processed
1,819 of the 16,666 datagrams in the same time with the threads spinning, and its clock fit
never became ready. How late the scans became available is printed, not asserted (timing belongs
in benchmarks).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import numpy as np

from insulator_rs.drivers.livox import LivoxMid360, wait_for

SENDER = Path(__file__).parent / "helpers" / "livox_realtime_sender.py"
SECONDS = 8.0
DRIFT = 25e-6
OFFSET_S = 5000.0


@pytest.mark.slow
def test_every_datagram_and_a_true_clock_fit_while_threads_hold_the_gil() -> None:
    driver = LivoxMid360(now=time.monotonic, T_b_l=np.eye(4), host_ip="127.0.0.1", point_port=0, imu_port=None,
                         keep_scans=1000, arrival_stamps=True).start()
    available: list[float] = []  # how late each scan reached the driver's buffer (s past its end)
    take = driver._take

    def timed_take(scan: object) -> None:
        take(scan)  # type: ignore[arg-type]
        available.append(time.monotonic() - driver._scans[-1].time_end)

    driver._take = timed_take  # type: ignore[method-assign]
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            x = 0
            for i in range(20000):
                x += i

    spinners = [threading.Thread(target=spin, daemon=True) for _ in range(2)]
    for t in spinners:
        t.start()
    try:
        sender = subprocess.run([sys.executable, str(SENDER), "127.0.0.1", str(driver.point_address[1]),
                                 str(SECONDS), str(OFFSET_S), str(DRIFT)], capture_output=True, text=True, timeout=120)
        assert sender.returncode == 0, sender.stderr
        words = sender.stdout.split()
        sent, first_host = int(words[1]), float(words[3])
        assert wait_for(lambda: driver.received() >= sent, 10.0), (driver.received(), sent)
    finally:
        stop.set()
        for t in spinners:
            t.join()
        driver.close()
    health = driver.health()
    print(f"datagrams {health['datagrams']} of {sent}, drift {health['clock_drift_ppm']:.1f} ppm, "
          f"batches {driver.batches} (largest {driver.largest_batch} packets), scans available "
          f"p50 {np.median(available):.3f} s p90 {np.percentile(available, 90):.3f} s max {max(available):.3f} s "
          "past their end")
    assert health["datagrams"] == sent and health["malformed"] == 0 and health["lost"] == 0
    assert health["receive_errors"] == 0 and health["unmapped_scans"] == 0
    # every 100 ms window of the stream but the one still open at the end
    assert len(available) >= round(SECONDS / 0.1) - 1
    # the truth: sensor = (1 + DRIFT) * host + OFFSET_S (the sender's clock)
    host = first_host + np.linspace(0.0, SECONDS, 81)
    sensor = (1.0 + DRIFT) * host + OFFSET_S
    error = np.abs(np.asarray(driver.clock.to_target(sensor)) - host)
    print(f"sensor -> host map: worst {error.max() * 1e3:.2f} ms over the stream")
    assert error.max() < 0.020
