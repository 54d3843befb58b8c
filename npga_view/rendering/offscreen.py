"""Pictures of an avatar drawn offscreen, one code at a time, as `npga-view render` writes them (PNG, NPY, the
frames of an MP4): the exact pose, an inspection mode with its legend, or the raw modes, the colour image through
the one pipeline of the window, Compare and the commands (`npga_view/rendering/pipeline.py`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.inspection.legend import format_value, legend_strip, to_display
from npga_view.rendering.pipeline import refine_frame
from npga_view.rendering.renderer import NEAR

if TYPE_CHECKING:
    from npga_core.inspection.inspector import InspectSettings
    from npga_core.model.avatar import Avatar
    from npga_core.model.cnn import ScreenCNN
    from npga_view.rendering.renderer import SplatRenderer

Vec3 = tuple[float, float, float]
Runner = Callable[[np.ndarray], np.ndarray]


class OffscreenFrames:
    """The avatar's picture at a code in one mode: posed exactly (`ExactPoses`), checked finite, then drawn in an
    inspection mode (with its legend strip below when `legend`), or as the raw rgb/alpha/depth/latent image, rgb
    through the one pipeline (`pipeline.refine_frame`, the avatar's CNN when `use_cnn`; `cnn_runner` runs it, e.g.
    interruptibly). `source` is named when a pose is not finite; `raw_npy`: depth and latent stay raw floats."""

    def __init__(self, avatar: Avatar, renderer: SplatRenderer, camera: Camera, mode: str, background: Vec3,
                 settings: InspectSettings, *, legend: bool = True, raw_npy: bool = False, use_cnn: bool = True,
                 precision: str = "fp32", source: str | Path = "", cnn_runner: Runner | None = None) -> None:
        from npga_core.inspection.inspector import Inspector
        from npga_core.posing.oneshot import ExactPoses

        self.avatar, self.renderer, self.camera = avatar, renderer, camera
        self.poses = ExactPoses(avatar, precision)
        self.source = source  # named when a pose overflows
        self.mode, self.background, self.legend = mode, background, legend
        self.raw_npy = raw_npy
        self.use_cnn = use_cnn and self.mode == "rgb" and avatar.cnn is not None
        self.cnn_runner = cnn_runner
        self.settings = settings
        shaping = self.settings.style != "splats" or self.settings.hist_action != "off" or self.settings.clip != "off"
        self.inspecting = ((self.mode not in ("rgb", "alpha") or shaping)
                           and not (self.raw_npy and self.mode in ("depth", "latent")))
        if self.mode in ("depth", "latent"):
            self.settings.mode = self.mode
        self.inspector = Inspector(avatar)
        self.counts: dict | None = None

    def render(self, code: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(raw float image, uint8 RGB picture); AvatarFileError naming `self.source` when the posed Gaussians
        are not finite (the file's numbers overflow in the dynamics or the pose)."""
        from npga_core.files.untrusted import finite_output

        r, cam = self.renderer, self.camera
        posed = self.poses.pose(code)
        finite_output({k: getattr(posed, k) for k in ("means", "quats", "scales", "opacities", "sh")},
                      self.source, "the posed Gaussians")
        if self.inspecting:
            return self._inspect(posed, code)
        r.set_gaussians(posed)
        if self.mode == "latent":
            if r.latent_dim == 0:
                raise ValueError("--mode latent: the avatar has no latent features")
            image = r.render_latent(cam)
            self._count(posed)
            return image, to_display(image, "latent")
        if self.mode == "depth":
            image = r.render(cam, mode="depth")
            self._count(posed)
            return image, to_display(image, "depth", r.render(cam, mode="alpha"))
        image = r.render(cam, self.background, self.mode)
        self._count(posed)
        if self.use_cnn:  # the one pipeline of the window, Compare and the commands
            image = refine_frame(r, cast("ScreenCNN", self.avatar.cnn), cam, self.background, rgb=image,
                                 runner=self.cnn_runner)
        return image, to_display(image, self.mode)

    def _inspect(self, posed, code) -> tuple[np.ndarray, np.ndarray]:
        r, cam, s = self.renderer, self.camera, self.settings
        frame = self.inspector.frame(s, posed, code, cam)
        r.show(frame)
        image = r.render(cam, self.background)
        self._count(posed)
        picture = to_display(image, "rgb")
        c = frame.colouring
        if c is not None and s.value_range is None and c.cmap is not None:
            s.value_range = (c.lo, c.hi)  # later frames of a video keep the first frame's range
        if self.legend:
            picture = np.concatenate([picture, self._legend(frame, posed)], axis=0)
        return image, picture

    def _visibility_note(self) -> str:
        s = self.settings
        notes = []
        if s.hist_action != "off":
            lo, hi = cast(tuple[float, float], s.hist_range)  # set with the action
            shown = "only" if s.hist_action == "filter" else "bright"
            notes.append(f"{s.hist_attr} {format_value(lo)}..{format_value(hi)} {shown}")
        if s.clip == "box":
            notes.append("clipped to a box")
        elif s.clip == "plane":
            normal = ", ".join(format_value(v) for v in s.clip_normal)
            notes.append(f"clipped by the plane n = {normal}")
        return "; ".join(notes)

    def _legend(self, frame, posed) -> np.ndarray:
        legend = self._legend_of(frame, posed)
        note = self._visibility_note()
        if note:
            import cv2

            cv2.putText(legend, note, (8, legend.shape[0] - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.33, (255, 210, 80), 1,
                        cv2.LINE_AA)
        return legend

    def _legend_of(self, frame, posed) -> np.ndarray:
        s, w = self.settings, self.camera.width
        if self.mode == "knn" and s.knn_show == "all":
            from npga_core.inspection.graph import knn_edges

            edges = knn_edges(self.inspector.graph(s.knn_k))
            c = self.inspector.edge_colouring(s.knn_colour, edges, posed.means)
            return legend_strip(w, f"{c.label}, k = {s.knn_k}, {len(edges):,} edges", c.cmap, c.lo, c.hi)
        if self.mode == "knn":
            return legend_strip(w, f"the {s.knn_k} nearest neighbours of Gaussian {s.picked} (canonical kNN graph)")
        c = frame.colouring
        if c is None:
            if frame.style == "splats":
                return legend_strip(w, "colour: the Gaussians' own (SH) colour")
            what = {"points": f"points: opaque discs of {s.point_px:g} px",
                    "ellipsoids": "ellipsoids: the 1-sigma ellipse of each Gaussian, shaded"}[frame.style]
            return legend_strip(w, what, notes=(f"SH colour; opacity < {self.renderer.style_min_opacity:g} hidden",))
        return legend_strip(w, c.label, c.cmap, c.lo, c.hi, c.notes)

    def _count(self, posed) -> None:
        if self.counts is None:
            c = self.inspector.counts(self.camera, posed, self.renderer.drawn_mask(), NEAR)
            self.counts = {"total": c.total, "in_frustum": c.in_frustum, "drawn": c.drawn,
                           "parts": {name: {"total": t, "in_frustum": f, "drawn": d} for name, t, f, d in c.parts}}
