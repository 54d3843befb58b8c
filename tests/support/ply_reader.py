"""A binary little-endian PLY vertex reader written from the PLY format, independent of npga_core's reader."""

from __future__ import annotations

import numpy as np

PLY_TYPES = {"float": "f4", "float32": "f4", "double": "f8", "uchar": "u1", "int": "i4"}


def read_vertices(path) -> np.ndarray:
    """A minimal binary little-endian PLY reader (independent of npga_core.files.ply): the vertex element as a
    structured array whose field names are the property names, in file order."""
    with open(path, "rb") as fh:
        assert fh.readline() == b"ply\n"
        props, count, fmt = [], None, None
        while True:
            words = fh.readline().decode("ascii").split()
            if words[0] == "end_header":
                break
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                assert words[1] == "vertex" and count is None, "expected one vertex element"
                count = int(words[2])
            elif words[0] == "property":
                props.append((words[2], "<" + PLY_TYPES[words[1]]))
        assert fmt == "binary_little_endian"
        data = np.frombuffer(fh.read(), dtype=np.dtype(props), count=count)
        assert fh.read() == b""
    return data
