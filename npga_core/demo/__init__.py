"""The bundled demo avatar: an NPGA-style avatar distilled from the ICT-FaceKit blendshape head.

`python -m npga_core.demo.build` rebuilds `assets/demo/` from a seed; `python scripts/demo_images.py`
renders the documentation images. See docs/DEMO.md.
"""
