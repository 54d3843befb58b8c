"""npga_view: the GL renderer, the viewer app, its panels and the `npga-view` command line."""

from npga_core import __version__

__all__ = ["__version__"]
