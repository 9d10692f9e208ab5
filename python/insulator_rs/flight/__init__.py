"""The flight loop: one single-flight inspection through real interfaces only.

:class:`~insulator_rs.flight.loop.FlightLoop` flies a mission through a
:class:`~insulator_rs.ports.vehicle.Vehicle`, reads a :class:`~insulator_rs.ports.sensors.Sensors`
source, runs a detector (a callable image -> boxes) and the
:class:`~insulator_rs.perception.pipeline.PerceptionPipeline`. It knows nothing of the
simulator or of ground truth (ARCHITECTURE.md states the rule; a test checks it).
"""
