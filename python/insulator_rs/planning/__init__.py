"""Planning: exploration path, waypoints, safety volumes, min-snap, PMM, TSP, segments."""
