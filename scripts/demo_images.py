"""Headless preview renders of the demo avatar for the documentation.

``python scripts/demo_images.py [--avatar assets/demo/avatar.npga] [--out docs/images]`` writes
``demo_<expression>_<view>.png`` for the neutral face from the front, three-quarter and side, and for the
jaw-open, smile, blink and other named expressions. Needs an OpenGL 4.3 context (EGL or OSMesa).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from npga_core.camera.cameras import Camera, frame_points
from npga_core.files.loading import DEMO_AVATAR, load_avatar
from npga_core.model.avatar import Avatar

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "images"
VIEWS = {"front": "front", "three_quarter": "three_quarter_right", "side": "right"}
#: (expression, views) rendered by default.
SHOTS: list[tuple[str, tuple[str, ...]]] = [
    ("neutral", ("front", "three_quarter", "side")),
    ("jaw_open", ("front", "three_quarter")),
    ("smile", ("front", "three_quarter")),
    ("blink", ("front",)),
    ("surprise", ("front",)),
    ("look_left", ("front",)),
]
BACKGROUND = (0.93, 0.93, 0.94)


def head_cameras(avatar: Avatar, width: int, height: int) -> dict[str, Camera]:
    """Cameras framing the head (the Gaussians above the chin-neck line) from each view."""
    m = np.asarray(avatar.cloud.means)
    head = m[m[:, 1] > np.percentile(m[:, 1], 12)]
    return {k: frame_points(head, width, height, fov=20.0, direction=d, margin=1.02) for k, d in VIEWS.items()}


def render_previews(avatar: Avatar, out: Path, width: int = 400, height: int = 580,
                    shots: list[tuple[str, tuple[str, ...]]] | None = None) -> list[Path]:
    """Render the shots to PNGs in `out`; returns the paths written."""
    from npga_view.rendering.gl import create_headless_context
    from npga_view.rendering.renderer import SplatRenderer

    ctx = create_headless_context()
    renderer = SplatRenderer(ctx, width, height)
    cams = head_cameras(avatar, width, height)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, views in shots or SHOTS:
        code = avatar.expression.named[name] if avatar.expression is not None else None
        renderer.set_gaussians(avatar.pose(code))
        for view in views:
            img = renderer.render(cams[view], background=BACKGROUND)
            rgb = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
            path = out / f"demo_{name}_{view}.png"
            cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
            written.append(path)
    renderer.release()
    return written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python scripts/demo_images.py", description=__doc__.splitlines()[0])
    p.add_argument("--avatar", type=Path, default=DEMO_AVATAR)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--size", type=int, nargs=2, default=(400, 580), metavar=("W", "H"))
    args = p.parse_args(argv)
    for path in render_previews(load_avatar(args.avatar), args.out, *args.size):
        print(f"{path} ({path.stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
