"""Live sensor drivers: adapters behind the ``Sensors`` port (see ``insulator_rs.ports.sensors``).

* :mod:`.livox`: Livox Mid-360 over UDP (SDK2 protocol, parsed in Rust);
* :mod:`.camera_source`: what every camera source shares (frames, thread, exposure stamps);
* :mod:`.camera`: a camera through OpenCV's VideoCapture (V4L2, stream, file);
* :mod:`.gstreamer_camera`: a GStreamer pipeline through PyGObject (the ``gstreamer`` extra);
* :mod:`.camera_select`: which of the two ``--camera SOURCE`` opens;
* :mod:`.live_sensors`: both behind one ``Sensors``.

Every stamp leaves a driver in the vehicle clock (``insulator_rs.timesync``).
"""
