"""Tracking: the registry of insulators found."""
