"""The autonomy half: mission file, geodesy, safety volumes, exploration path,
inspection waypoints, insulator registry, the online state machine, trajectory
planners (minimum-snap, point-mass model), the exact TSP baseline and the
``insulator-rs inspect`` command. Everything is in the world frame W (local ENU
at the inspected tower's base, metres, radians, seconds)."""
