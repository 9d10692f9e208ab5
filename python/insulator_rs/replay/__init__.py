"""Replay of a recorded flight through the flight's own perception runner; the Ray fleet."""
