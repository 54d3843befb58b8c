"""Comparison views: the avatar against a capture or a second avatar (see view.py)."""
