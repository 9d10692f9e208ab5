"""Perception: pairing, the fusion pipeline, the shape check, photo quality."""
