"""npga_core: the NPGA avatar model, its file formats and maths (numpy + torch, no GL, no UI)."""

__version__ = "0.1.0"
