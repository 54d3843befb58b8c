"""Shared fixtures: small synthetic avatars written to temporary files."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest

from npga_core.files.checkpoint import ALIGN, MAGIC, save_avatar
from npga_core.model.synthetic import make_synthetic_avatar


@pytest.fixture(scope="module")
def ctx():
    """A headless OpenGL 4.3 context (EGL, else OSMesa). Skipped where there is none, except under CI."""
    from npga_view.rendering.gl import GLUnavailableError, create_headless_context

    try:
        context = create_headless_context()
    except GLUnavailableError as exc:
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no OpenGL 4.3 context: {exc}")
    yield context
    context.release()


@pytest.fixture(scope="session")
def small_avatar():
    """A 600-Gaussian avatar with paper-sized networks, latent features and a CNN."""
    return make_synthetic_avatar(600, latent_dim=4, with_cnn=True, seed=3)


@pytest.fixture(scope="session")
def small_npga(tmp_path_factory, small_avatar) -> Path:
    path = tmp_path_factory.mktemp("avatars") / "small.npga"
    save_avatar(small_avatar, path)
    return path


def split_npga(path: Path) -> tuple[dict, bytes]:
    """(header, data section) of a .npga file, for tests that tamper with files."""
    raw = path.read_bytes()
    hlen = int.from_bytes(raw[8:16], "little")
    return json.loads(raw[16 : 16 + hlen]), raw[16 + hlen :]


def write_npga(path: Path, header: dict, data: bytes) -> Path:
    """Write a header and data section with correct framing (the inverse of split_npga)."""
    text = json.dumps(header).encode()
    pad = (-(16 + len(text))) % ALIGN
    text += b" " * pad
    path.write_bytes(MAGIC + len(text).to_bytes(8, "little") + text + data)
    return path


@pytest.fixture
def tamper(tmp_path, small_npga) -> Callable[[Callable[[dict, bytearray], None]], Path]:
    """Copy the small avatar with the header and data changed in place by `mutate(header, data)`."""

    def make(mutate: Callable[[dict, bytearray], None], name: str = "bad.npga") -> Path:
        header, data = split_npga(small_npga)
        data = bytearray(data)
        mutate(header, data)
        return write_npga(tmp_path / name, header, bytes(data))

    return make

# an action nobody handles, or one with fields of the wrong types, raises in tests (npga_view/actions.py)
os.environ.setdefault("NPGA_VIEW_STRICT_ACTIONS", "1")
