"""Shared test helpers: the small scene, PX4 SITL and ground-station drivers, reference
algorithms, report readers. Test modules import from here, never from one another."""
