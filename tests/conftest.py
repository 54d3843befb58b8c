"""Shared fixtures: a headless GL context, small synthetic avatars written to temporary files, and the real
window under Xvfb (tests/support/window.py holds the helpers that drive it)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from npga_core.files.checkpoint import save_avatar
from npga_core.files.loading import DEMO_AVATAR
from npga_core.model.synthetic import make_synthetic_avatar
from tests.support.npga_files import split_npga, write_npga
from tests.support.window import Display
from tests.support.xvfb import stop


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


@pytest.fixture(scope="module", params=["43", "41", "cpu"], ids=["gl43", "gl41", "cpu"])
def gl_path(request, ctx) -> str:
    """The splat renderer path a test runs on, in turn: "43" (its GL colour pass), "41" (the OpenGL 4.1 path: CPU
    pre-pass, texture splats, forced on this machine's 4.3+ context) and "cpu" (the 4.3 path with the colour pass
    on the CPU, what a software GL gets: npga_view/rendering/cpu_splats.py), so every renderer test checks all
    three. Where the context is older than 4.3 (macOS), "43" and "cpu" are skipped. tests/view/test_gl41.py runs
    the 4.1 path in a real 4.1 context."""
    if request.param in ("43", "cpu") and ctx.version_code < 430:
        pytest.skip("the OpenGL 4.3 path needs a 4.3 context")
    if request.param == "cpu":
        from npga_view.rendering.cpu_splats import status, warm_up

        assert warm_up(wait=True), f"the CPU colour pass did not compile: {status()}"
    return request.param


@pytest.fixture(scope="module")
def make_renderer(ctx, gl_path) -> Callable[..., Any]:
    """`make_renderer(width, height, exact_sort=True, context=None)`: a splat renderer on `gl_path`'s path (in
    `ctx`, or in `context`) through npga_view.rendering.factory.create_renderer; the test releases it."""
    from npga_view.rendering.factory import create_renderer

    def make(width: int, height: int, exact_sort: bool = True, context: Any = None) -> Any:
        path = "43" if gl_path == "cpu" else gl_path
        return create_renderer(context if context is not None else ctx, width, height, exact_sort, path=path,
                               cpu_colour=gl_path == "cpu")

    return make


@pytest.fixture(scope="session")
def small_avatar():
    """A 600-Gaussian avatar with paper-sized networks, latent features and a CNN."""
    return make_synthetic_avatar(600, latent_dim=4, with_cnn=True, seed=3)


@pytest.fixture(scope="session")
def small_npga(tmp_path_factory, small_avatar) -> Path:
    path = tmp_path_factory.mktemp("avatars") / "small.npga"
    save_avatar(small_avatar, path)
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

@pytest.fixture(scope="module")
def xserver():
    try:
        d = Display()
    except RuntimeError as e:
        if os.environ.get("CI"):
            raise
        pytest.skip(str(e))
    old = os.environ.get("DISPLAY")
    yield d
    if old is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = old
    stop(d.proc)


@pytest.fixture
def display(xserver):
    return xserver.ensure()


@pytest.fixture(scope="module")
def avatar_path(tmp_path_factory):
    """The demo avatar when it is built, else a small synthetic one."""
    if DEMO_AVATAR.is_file():
        return "demo"
    p = tmp_path_factory.mktemp("gui") / "syn.npga"
    save_avatar(make_synthetic_avatar(3000, seed=2), p)
    return str(p)


@pytest.fixture
def app(display, xserver, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    from npga_view.app import ViewerApp

    for attempt in range(3):  # an Xvfb connection was once refused under load: retry, restarting it if gone
        try:
            a = ViewerApp(1000, 990, vsync=False, threads=1, remember_recent=False)
            break
        except RuntimeError:
            if attempt == 2:
                raise
            time.sleep(1.0)
            xserver.ensure()
    yield a
    a.close()
# an action nobody handles, or one with fields of the wrong types, raises in tests (npga_view/actions.py)
os.environ.setdefault("NPGA_VIEW_STRICT_ACTIONS", "1")
