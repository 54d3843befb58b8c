"""Holding an avatar against a multi-view capture: image metrics and capture readers."""
