"""A valid mission as the dict a mission file parses to (the smallest one with a tower, two
neighbours, the vehicle's limits and the inspection's standoff): tests change one field of a
copy."""

GOOD_MISSION = {
    "tower": {"lat": 50.0, "lon": 14.0, "alt": 300.0, "max_height": 25.0, "max_width": 10.0},
    "neighbours": [{"lat": 50.0, "lon": 13.997, "alt": 300.0},
                   {"lat": 50.0, "lon": 14.003, "alt": 301.0}],
    "vehicle": {"v_max_horizontal": 1.0, "a_max_horizontal": 3.0,
                "v_max_vertical": 1.0, "a_max_vertical": 3.0},
    "inspection": {"standoff": 8.0, "safety_margin": 2.0},
}
