"""A Mid-360 played in real time, in a process of its own: the load test's sensor.

``python tests/livox_realtime_sender.py HOST PORT SECONDS OFFSET_S DRIFT``: renders SECONDS of
10 Hz scans of a room (the simulator's Mid-360 model), encodes them as Livox SDK2 datagrams on
a sensor clock ``sensor = (1 + DRIFT) * host + OFFSET_S`` (host = ``time.monotonic``), and sends
each datagram when the host clock reaches its last shot's time, as the hardware does. Prints
``sent N`` and the host time of the first shot. A process of its own so that the receiving
process's load does not make the sensor late: a real LiDAR is never late.
"""

from __future__ import annotations

import socket
import sys
import time

import numpy as np

from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.livox_emitter import LivoxEmitter, SensorClock
from insulator_rs.sim.mesh import Mesh, plane

FRAME_S = 0.1


def room(half: float = 12.0) -> Mesh:
    walls = [plane([half, 0, 10], [-1, 0, 0], (40, 40), instance_id=1),
             plane([-half, 0, 10], [1, 0, 0], (40, 40), instance_id=2),
             plane([0, half, 10], [0, -1, 0], (40, 40), instance_id=3),
             plane([0, -half, 10], [0, 1, 0], (40, 40), instance_id=4)]
    return Mesh.concatenate([plane([0, 0, 0], [0, 0, 1], (40, 40), instance_id=0), *walls])


def main(argv: list[str]) -> int:
    host, port, seconds, offset_s, drift = argv[0], int(argv[1]), float(argv[2]), float(argv[3]), float(argv[4])
    clock = SensorClock(offset_s=offset_s, drift=drift)
    lidar, mesh = Mid360(), room()
    pose = np.eye(4)
    pose[2, 3] = 3.0
    n = int(round(seconds / FRAME_S))
    # rendered first (on the relative time axis), then sent on the host clock
    frames = [lidar.scan(mesh, lambda t: pose, FRAME_S * k, seed=k) for k in range(n)]
    t0 = time.monotonic() + 0.5
    emitter = LivoxEmitter(clock=SensorClock(offset_s=offset_s + (1.0 + drift) * t0, drift=drift))
    emitter.start_at(frames[0].t_start)
    datagrams = [d for f in frames for d in emitter.add_frame(f)] + emitter.finish()
    # each datagram leaves when its last shot has been taken (its header stamp + its span)
    stamps = np.array([int.from_bytes(d[28:36], "little") + 100 * int.from_bytes(d[3:5], "little")
                       for d in datagrams], np.float64) * 1e-9
    due = clock.to_vehicle(stamps)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = 0
    for d, at in zip(datagrams, due):
        wait = at - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        sock.sendto(d, (host, port))
        sent += 1
    print(f"sent {sent} first {t0:.6f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
