"""Target images for the demo's screen-space refinement: the ICT head itself, posed and shaded per pixel.

`HeadRenderer` draws what the demo's Gaussians approximate, without the approximations: the kit's mesh posed
exactly by the blendshapes (and the gaze rotation), rasterised with 2 x 2 samples per pixel, and coloured at
every sample by the same colour model the Gaussians were given (`colors.AlbedoModel` evaluated at the sample's
canonical surface point, so lip contour, brows, hairline, iris streaks and pupil are as sharp as the image; the
per-sample jitter interpolated), with the same baked key light and cavity term (cavity per vertex against the
Gaussian centres, interpolated), G's expression-dependent darkening (compression wrinkles with their stripes,
the mouth interior as the jaw opens) computed per pixel from the posed mesh, and the SH facing term with the
posed normal. Only the surfaces the Gaussians sample are drawn.
"""

from __future__ import annotations

import numpy as np
import torch

from npga_core.camera.cameras import Camera
from npga_core.demo.canonical import CanonicalBuild
from npga_core.demo.colors import AlbedoModel, bake_lighting, cavity
from npga_core.demo.ict import PART_NAMES, IctHead, pose_vertices
from npga_core.demo.mesh_raster import box_filter, rasterize_mesh, supersampled
from npga_core.demo.sampling import DEFAULT_DENSITY, interpolate, label_iris, sampleable_density, tangent_frames
from npga_core.demo.targets import VertexGradients, darkening, min_stretch, shading_weights


class HeadRenderer:
    """Renders target images of the ICT head for blendshape weights and a camera (see the module docstring)."""

    def __init__(self, head: IctHead, canon: CanonicalBuild, albedo: AlbedoModel, supersample: int = 2):
        self.head = head
        self.canon = canon
        self.albedo = albedo
        self.supersample = supersample
        self.tri = np.flatnonzero(sampleable_density(head, DEFAULT_DENSITY) > 0)
        self.faces = head.faces[self.tri]
        self.normals0 = head.vertex_normals()
        self.cavity0 = cavity(head.vertices.astype(np.float64), self.normals0.astype(np.float64),
                              reference=canon.samples.points.astype(np.float64))
        self.gradients = VertexGradients(head)
        self.jaw = head.expression_index("jawOpen")
        self._cache: tuple | None = None

    def posed_mesh(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
        """Posed vertices, their normals and the vertex deformation gradients (cached for the last weights)."""
        key = np.asarray(weights, np.float32).tobytes()
        if self._cache is None or self._cache[0] != key:
            w = torch.from_numpy(np.asarray(weights, np.float32))[None]
            verts = pose_vertices(self.head, w)[0].numpy()
            self._cache = (key, verts, self.head.vertex_normals(verts), self.gradients(w)[0])
        return self._cache[1:]

    def render(self, weights: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(premultiplied colour (H, W, 3), coverage (H, W)) at blendshape weights (E,), both float32."""
        s = self.supersample
        verts, normals, fv = self.posed_mesh(weights)
        frags = rasterize_mesh(verts, self.faces, supersampled(camera, s))
        cov = frags.covered
        colour = np.zeros(frags.triangle.shape + (3,))
        if cov.any():
            colour[cov] = self.shade(verts, normals, fv, self.tri[frags.triangle[cov]], frags.bary[cov], weights,
                                      camera)
        rgb = box_filter(colour, s).astype(np.float32)
        return rgb, box_filter(cov.astype(np.float64), s).astype(np.float32)

    def shade(self, verts: np.ndarray, normals: np.ndarray, fv: torch.Tensor, tri: np.ndarray, bary: np.ndarray,
               weights: np.ndarray, camera: Camera) -> np.ndarray:
        head = self.head
        faces = head.faces
        rest = interpolate(head.vertices, faces, tri, bary).astype(np.float32)
        part = label_iris(head, rest, head.tri_part[tri])
        n0 = interpolate(self.normals0, faces, tri, bary)
        n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
        base = self.albedo.evaluate(head, rest, part, tri, bary.astype(np.float32), self.albedo.jitter_at(rest, part))
        strength = np.where(part == PART_NAMES.index("teeth"), 0.5, 1.0)
        c = bake_lighting(base, n0, interpolate(self.cavity0, faces, tri, bary), occlusion_strength=strength)
        # G's darkening, per pixel from the posed mesh
        corners = torch.from_numpy(faces[tri])
        b = torch.from_numpy(bary.astype(np.float32))
        fg = (fv[corners] * b[:, :, None, None]).sum(dim=1)
        fg = torch.where((torch.linalg.det(fg) > 1e-6)[:, None, None], fg, torch.eye(3))
        axes = torch.from_numpy(tangent_frames(n0)[:, :, :2])
        sw = shading_weights(head, rest, part)
        dark = darkening(min_stretch(fg @ axes), torch.tensor(float(weights[self.jaw])), sw["skin"],
                         sw["stripe_weight"], sw["stripe"], sw["mouth_depth"]).numpy()[:, None]
        # the SH facing term with the posed normal: c (1 - a) (1 - dark) + a c cos(view angle)
        n1 = interpolate(normals, faces, tri, bary)
        n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
        p1 = interpolate(verts, faces, tri, bary).astype(np.float64)
        d = p1 - camera.camera_center
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        a = self.canon.facing
        cos_view = -(n1 * d).sum(axis=1, keepdims=True)
        return np.maximum(c * (1.0 - a) * (1.0 - dark) + a * c * cos_view, 0.0)
