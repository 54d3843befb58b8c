"""Data package `npga_core.assets`: pyproject.toml maps this folder into npga_core (wheel, sdist, editable).

It holds the bundled demo avatar (demo/, with the ICT-FaceKit licence); code finds it with
`npga_core.files.places.bundled_path`, never by a path into the source tree.
"""
