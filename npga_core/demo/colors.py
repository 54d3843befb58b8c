"""Plausible per-part colours for the demo head, baked soft lighting, and conversion to degree-1 SH.

The albedo is procedural: skin with low-frequency variation, redder lips, cheeks and nose, brows and short
dark hair at the back, a sclera, an iris with pupil and limbal ring, teeth, gums and a dark mouth socket.
Lighting is baked like in a captured avatar: a soft key light and a cavity (ambient-occlusion) term in the
DC colour, plus a facing-ratio term in the degree-1 SH so surfaces darken gently towards grazing views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from npga_core.demo.ict import LIMBUS_ANGLE, PART_NAMES, IctHead
from npga_core.demo.sampling import SurfaceSamples
from npga_core.model.gaussians import rgb_to_sh0

SH_C1 = 0.4886025119029199
CM = 0.01

SKIN = np.array([0.80, 0.60, 0.50])
LIPS = np.array([0.68, 0.36, 0.36])
BROW = np.array([0.26, 0.18, 0.13])
HAIR = np.array([0.15, 0.105, 0.08])
SCLERA = np.array([0.93, 0.91, 0.88])
IRIS = np.array([0.32, 0.42, 0.48])
PUPIL = np.array([0.02, 0.02, 0.025])
TEETH = np.array([0.93, 0.90, 0.82])
GUMS = np.array([0.76, 0.38, 0.40])
SOCKET = np.array([0.36, 0.12, 0.12])
EYE_SOCKET = np.array([0.62, 0.36, 0.34])

#: Soft key light (from the upper front left of the viewer) and its ambient share.
KEY_LIGHT = np.array([0.35, 0.55, 1.0]) / np.linalg.norm([0.35, 0.55, 1.0])


def smoothstep(e0: float | np.ndarray, e1: float | np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True)
class FourierNoise:
    """Smooth noise in about [-1, 1]: a sum of random plane waves with wavelengths in a given range."""

    directions: np.ndarray  # (terms, 3) unit
    wavenumbers: np.ndarray  # (terms,)
    phase: np.ndarray  # (terms,)

    @staticmethod
    def draw(rng: np.random.Generator, wavelengths: tuple[float, float], terms: int = 8) -> FourierNoise:
        d = rng.normal(size=(terms, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        k = 2 * np.pi / rng.uniform(*wavelengths, size=terms)
        phase = rng.uniform(0, 2 * np.pi, size=terms)
        return FourierNoise(d, k, phase)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        terms = len(self.phase)
        return np.sin(points @ (self.directions * self.wavenumbers[:, None]).T + self.phase).sum(axis=1) / np.sqrt(
            terms / 2)


def _blob(points: np.ndarray, centre: npt.ArrayLike, radius: float) -> np.ndarray:
    return np.exp(-0.5 * np.sum((points - np.asarray(centre) * CM) ** 2, axis=1) / (radius * CM) ** 2)


def polygon_signed_distance(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) of 2-D points to a closed polygon."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(((xy[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    dist = np.linalg.norm(xy[:, None] - (a + t[..., None] * ab), axis=2).min(axis=1)
    crosses = ((a[:, 1] > xy[:, None, 1]) != (b[:, 1] > xy[:, None, 1])) & (
        xy[:, None, 0] < a[:, 0] + (xy[:, None, 1] - a[:, 1]) * ab[:, 0] / np.where(ab[:, 1] == 0, 1e-12, ab[:, 1]))
    inside = crosses.sum(axis=1) % 2 == 1
    return np.where(inside, -dist, dist)


def lip_weight(head: IctHead, points: np.ndarray, part: np.ndarray, soft: float = 0.0012) -> np.ndarray:
    """1 on the lips (inside the outer lip contour, seen from the front, incl. the inner lip), 0 elsewhere."""
    outline = head.landmark_points(range(48, 60))
    sd = polygon_signed_distance(points[:, :2], outline[:, :2])
    front = smoothstep(outline[:, 2].min() - 0.025, outline[:, 2].min() - 0.015, points[:, 2])
    return (1.0 - smoothstep(-soft, soft, sd)) * front * (part == PART_NAMES.index("face"))


def eyelid_mask(head: IctHead, tri: np.ndarray, bary: np.ndarray, part: np.ndarray, threshold: float = 0.002
                ) -> np.ndarray:
    """Face samples that a full blink moves by more than `threshold` metres: the eyelids."""
    move = np.zeros(len(tri))
    for name in ("eyeBlink_L", "eyeBlink_R"):
        d = head.deltas[head.expression_index(name)][head.faces[tri]]
        move = np.maximum(move, np.linalg.norm((d * bary[..., None]).sum(axis=1), axis=1))
    return (move > threshold) & (part == PART_NAMES.index("face"))


def _polyline_distance(p: np.ndarray, line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of 2-D points to a polyline and the arc-length parameter in [0, 1] of the closest point."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(((p[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    d = np.linalg.norm(p[:, None] - (a + t[..., None] * ab), axis=2)
    seg = d.argmin(axis=1)
    lengths = np.linalg.norm(ab, axis=1)
    cum = np.r_[0.0, np.cumsum(lengths)]
    s = (cum[seg] + t[np.arange(len(p)), seg] * lengths[seg]) / cum[-1]
    return d.min(axis=1), s


def brow_weight(head: IctHead, points: np.ndarray, part: np.ndarray) -> np.ndarray:
    """Soft eyebrow mask: a band above each brow landmark line, thick at the inner end, thin at the tail."""
    w = np.zeros(len(points))
    face = part == PART_NAMES.index("face")
    for ids in (range(21, 16, -1), range(22, 27)):  # from the inner end outwards
        marks = head.landmark_points(ids)
        d, s = _polyline_distance(points[:, :2], marks[:, :2] + np.array([0.0, 0.15 * CM]))
        half = (0.42 - 0.22 * s) * CM
        front = points[:, 2] > marks[:, 2].min() - 2.0 * CM
        w = np.maximum(w, (1.0 - smoothstep(0.5 * half, 1.4 * half, d)) * front * face)
    return w


def hair_weight(points: np.ndarray, part: np.ndarray, noise: FourierNoise) -> np.ndarray:
    """Short hair over the scalp: above a hairline (moved by `noise`) that runs from the forehead over the ears
    to the nape."""
    p = points / CM
    theta = np.degrees(np.abs(np.arctan2(p[:, 0], p[:, 2] - 1.0)))
    line = np.interp(theta, [0, 30, 55, 80, 100, 125, 150, 180], [10.6, 10.0, 8.6, 6.8, 6.2, 3.0, -2.0, -2.8])
    line = line + 0.18 * noise(points)
    scalp = np.isin(part, [PART_NAMES.index("face"), PART_NAMES.index("head_neck")])
    return smoothstep(line - 0.25, line + 0.45, p[:, 1]) * scalp


def eye_colours(head: IctHead, points: np.ndarray, part: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """Sclera, iris (radial streaks with random `phase` (4,), darker limbal ring) and pupil colours of eye-shell
    points."""
    out = np.zeros((len(points), 3))
    for e, names in enumerate((("sclera_l", "iris_l"), ("sclera_r", "iris_r"))):
        m = np.isin(part, [PART_NAMES.index(n) for n in names])
        d = points[m] - head.eye_centres[e]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        ax = head.eye_axes[e]
        ang = np.arccos(np.clip(d @ ax, -1.0, 1.0))
        u = np.cross(ax, [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        phi = np.arctan2(d @ np.cross(ax, u), d @ u)
        r = ang / LIMBUS_ANGLE
        streak = 1.0 + 0.12 * np.sin(23 * phi + phase[0]) + 0.08 * np.sin(41 * phi + phase[1])
        iris = IRIS * streak[:, None] * (1.0 + 0.25 * smoothstep(0.35, 0.6, r)[:, None])
        iris = iris * (1.0 - 0.55 * smoothstep(0.78, 1.0, r))[:, None]
        iris = np.where((r < 0.32)[:, None], PUPIL, iris)
        iris = np.where((r >= 0.32)[:, None] & (r < 0.38)[:, None], 0.5 * (PUPIL + iris), iris)
        sclera = SCLERA - np.array([0.02, 0.12, 0.12]) * smoothstep(1.6, 3.2, r)[:, None]
        out[m] = np.where((r < 1.0)[:, None], iris, sclera)
    return out


#: Parts whose colour is a flat colour with a per-sample jitter, in the order their jitter is drawn.
_FLAT_PARTS = ("mouth_socket", "gums_tongue", "teeth", "eye_socket_l", "eye_socket_r")


@dataclass
class AlbedoModel:
    """The random draws of the procedural albedo: noise fields, the iris phase and per-sample jitter.

    `draw` consumes the generator exactly as the albedo of the shipped build did, so `evaluate` at the samples
    reproduces the avatar's colours bit for bit; `evaluate` at any other surface point (a pixel of a mesh render)
    gives the same colour function at full resolution, with the per-sample jitter interpolated (`jitter_at`).
    """

    skin: FourierNoise
    hue: FourierNoise
    lips: FourierNoise
    hairline: FourierNoise
    eye_phase: np.ndarray  # (4,)
    jitter: np.ndarray  # (N, 4) normal draws per sample: skin grain, brow, hair, flat parts
    points: np.ndarray  # (N, 3) the samples the jitter belongs to
    part: np.ndarray  # (N,)

    @staticmethod
    def draw(samples: SurfaceSamples, rng: np.random.Generator) -> AlbedoModel:
        n, part = len(samples), samples.part
        jitter = np.zeros((n, 4))
        skin = FourierNoise.draw(rng, (0.03, 0.09))
        hue = FourierNoise.draw(rng, (0.02, 0.06))
        jitter[:, 0] = rng.standard_normal((n, 1))[:, 0]
        lips = FourierNoise.draw(rng, (0.004, 0.01))
        jitter[:, 1] = rng.standard_normal((n, 1))[:, 0]
        hairline = FourierNoise.draw(rng, (0.03, 0.06), terms=6)
        jitter[:, 2] = rng.standard_normal((n, 1))[:, 0]
        for name in _FLAT_PARTS:
            m = part == PART_NAMES.index(name)
            jitter[m, 3] = rng.standard_normal((int(m.sum()), 1))[:, 0]
        eye_phase = rng.uniform(0, 2 * np.pi, size=4)
        return AlbedoModel(skin, hue, lips, hairline, eye_phase, jitter, samples.points, part)

    def jitter_at(self, points: np.ndarray, part: np.ndarray, k: int = 4) -> np.ndarray:
        """Per-sample jitter interpolated (inverse distance, k nearest samples of the same part) at `points`."""
        out = np.zeros((len(points), self.jitter.shape[1]))
        for pid in np.unique(part):
            q = np.flatnonzero(part == pid)
            src = np.flatnonzero(self.part == pid)
            if len(src) == 0:
                continue
            kk = min(k, len(src))
            dist, j = cKDTree(self.points[src]).query(points[q], k=kk)
            dist, j = dist.reshape(len(q), kk), j.reshape(len(q), kk)
            w = 1.0 / np.maximum(dist, 1e-5)
            out[q] = (self.jitter[src[j]] * (w / w.sum(axis=1, keepdims=True))[..., None]).sum(axis=1)
        return out

    def evaluate(self, head: IctHead, points: np.ndarray, part: np.ndarray, tri: np.ndarray, bary: np.ndarray,
                 jitter: np.ndarray | None = None) -> np.ndarray:
        """Base colour (M, 3) in [0, 1] at surface points (float32 positions, part ids, triangles, barycentrics);
        `jitter` (M, 4) defaults to the samples' own (then the points must be the samples)."""
        jitter = self.jitter if jitter is None else jitter
        p = points.astype(np.float64)
        n = len(p)
        col = np.tile(SKIN, (n, 1))
        # low-frequency skin variation (blotchiness, a slight hue drift) and a fine grain
        col *= 1.0 + 0.035 * self.skin(p)[:, None]
        col[:, 0] *= 1.0 + 0.02 * self.hue(p)
        col *= 1.0 + 0.012 * jitter[:, 0:1]
        red = (0.8 * (_blob(p, (4.4, 0.2, 9.6), 1.8) + _blob(p, (-4.4, 0.2, 9.6), 1.8))  # cheeks
               + 0.6 * _blob(p, (0, 0.5, 12.8), 1.0)  # nose tip
               + 0.5 * (_blob(p, (7.6, 1.5, 0.5), 1.8) + _blob(p, (-7.6, 1.5, 0.5), 1.8)))  # ears
        col += red[:, None] * np.array([0.03, -0.05, -0.04])
        under_eye = _blob(p, (3.2, 2.2, 9.6), 0.8) + _blob(p, (-3.2, 2.2, 9.6), 0.8)
        col *= (1.0 - 0.06 * under_eye)[:, None]
        lip = lip_weight(head, points, part)[:, None]
        col = (1 - lip) * col + lip * LIPS * (1.0 + 0.04 * self.lips(p))[:, None]
        lids = eyelid_mask(head, tri, bary, part)[:, None]  # lids slightly darker and pinker
        col = np.where(lids, col * np.array([0.95, 0.9, 0.9]), col)
        brow = 0.72 * brow_weight(head, points, part)[:, None]
        col = (1 - brow) * col + brow * BROW * (1.0 + 0.15 * jitter[:, 1:2])
        hair = hair_weight(points, part, self.hairline)[:, None]
        col = (1 - hair) * col + hair * HAIR * (1.0 + 0.12 * jitter[:, 2:3])

        def depth(z0: float, z1: float) -> np.ndarray:  # 1 at the lips, falling off into the mouth
            return 0.45 + 0.55 * smoothstep(z0 * CM, z1 * CM, p[:, 2])

        shades: dict[str, tuple[np.ndarray, np.ndarray | float]] = {
            "mouth_socket": (SOCKET, depth(3.0, 9.5)), "gums_tongue": (GUMS, depth(3.0, 10.0)),
            "teeth": (TEETH, 0.7 + 0.3 * smoothstep(6.0 * CM, 10.0 * CM, p[:, 2])),
            "eye_socket_l": (EYE_SOCKET, 1.0), "eye_socket_r": (EYE_SOCKET, 1.0)}
        for name in _FLAT_PARTS:
            c, shade = shades[name]
            m = part == PART_NAMES.index(name)
            col[m] = c * np.broadcast_to(shade, (n,))[m, None] * (1.0 + 0.03 * jitter[m, 3:4])
        eyes = np.isin(part, [PART_NAMES.index(k) for k in ("sclera_l", "iris_l", "sclera_r", "iris_r")])
        col[eyes] = eye_colours(head, points, part, self.eye_phase)[eyes]
        return np.clip(col, 0.0, 1.0)


def albedo(head: IctHead, samples: SurfaceSamples, rng: np.random.Generator) -> np.ndarray:
    """Procedural base colour (N, 3) in [0, 1] of every sample."""
    return AlbedoModel.draw(samples, rng).evaluate(head, samples.points, samples.part, samples.tri, samples.bary)


def cavity(points: np.ndarray, normals: np.ndarray, radius: float = 0.012, k: int = 64,
           reference: np.ndarray | None = None) -> np.ndarray:
    """Ambient-occlusion-like cavity term in [0, 1]: mean elevation of nearby samples above the tangent plane.

    The samples are `points` themselves (each point's own entry left out) or, if given, the `reference` points.
    """
    if reference is None:
        dist, idx = cKDTree(points).query(points, k=k + 1, distance_upper_bound=radius)
        dist, idx = dist[:, 1:], idx[:, 1:]
        ref = points
    else:
        dist, idx = cKDTree(reference).query(points, k=k, distance_upper_bound=radius)
        ref = reference
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, 0)
    d = ref[idx] - points[:, None]
    elev = (d * normals[:, None]).sum(-1) / np.maximum(dist, 1e-9)
    elev = np.where(valid, np.clip(elev, 0.0, 1.0), 0.0)
    return elev.sum(axis=1) / np.maximum(valid.sum(axis=1), 1)


def bake_lighting(rgb: np.ndarray, normals: np.ndarray, occlusion: np.ndarray, ambient: float = 0.62,
                  occlusion_strength: float | np.ndarray = 1.0) -> np.ndarray:
    """Colour under a soft wrap-around key light, darkened in cavities (strength per sample or global)."""
    wrap = np.clip((normals @ KEY_LIGHT + 0.4) / 1.4, 0.0, 1.0)
    light = ambient + (1.0 - ambient) * wrap / 0.95
    ao = np.clip(1.0 - occlusion_strength * occlusion, 0.45, 1.0)
    return np.clip(rgb * (light * ao)[:, None], 0.0, 1.0)


def colours_to_sh(rgb: np.ndarray, normals: np.ndarray, facing: float = 0.22) -> np.ndarray:
    """Degree-1 SH (N, 4, 3): colour `rgb` seen head-on, darker by up to `facing` at grazing angles.

    The 3DGS basis evaluates ``-C1 y sh1 + C1 z sh2 - C1 x sh3`` for the unit direction camera -> Gaussian d,
    so ``sh_{1,2,3} = a c (n_y, -n_z, n_x) / C1`` adds ``-a c (n . d) = a c cos(view angle)``.
    """
    rgb = np.asarray(rgb, np.float32)
    n = np.asarray(normals, np.float32)
    sh = np.zeros((len(rgb), 4, 3), np.float32)
    sh[:, 0] = rgb_to_sh0(rgb * (1.0 - facing))
    coef = facing * rgb / SH_C1
    sh[:, 1] = coef * n[:, 1:2]
    sh[:, 2] = -coef * n[:, 2:3]
    sh[:, 3] = coef * n[:, 0:1]
    return sh
