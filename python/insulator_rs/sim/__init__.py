"""The built-in simulator: tower scenes, ray-cast LiDAR and camera, a kinematic multirotor.

Submodules are imported explicitly (``from insulator_rs.sim import towers``) so that
importing the package stays cheap.
"""
