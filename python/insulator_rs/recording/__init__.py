"""Recorded flights: ROS 2 messages in MCAP written during a flight, and replay of MCAP files,
rosbag2 folders (sqlite3 or MCAP) and ROS 1 bags through the flight's perception pipeline.

No ROS install is needed: messages are (de)serialised with ``rosbags``' own type system,
and MCAP files are written with the ``mcap`` library. Modules: :mod:`.types` (message types
and topic names), :mod:`.convert` (sensor data <-> ROS messages), :mod:`.writer` (the MCAP
writer and the recording wrappers), :mod:`.reader` (a bag as a time-ordered stream with
checks), :mod:`.replay` (one flight re-processed), :mod:`.fleet` (many, on Ray).
"""
