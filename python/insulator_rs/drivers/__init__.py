"""Live sensor drivers: adapters behind the ``Sensors`` port (see ``insulator_rs.ports.sensors``).

* :mod:`.livox`: Livox Mid-360 over UDP (SDK2 protocol, parsed in Rust);
* :mod:`.camera`: a camera through OpenCV's VideoCapture (V4L2, GStreamer, file);
* :mod:`.live_sensors`: both behind one ``Sensors``.

Every stamp leaves a driver in the vehicle clock (``insulator_rs.timesync``).
"""
