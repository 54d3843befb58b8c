"""Looking inside an avatar: per-Gaussian colour modes, counts, histograms, clipping, kNN lines.

The pieces live in small modules: colour maps and colourings in `colouring.py`, per-Gaussian measures, counts,
ranges, clipping and recolouring in `measures.py`, the expression sensitivity (exact JVPs through F and G) in
`sensitivity.py`; this module holds the offset values, the settings and the `Inspector` that ties them together.

Every colour mode is a function that returns a `Colouring`: an RGB in [0, 1] per Gaussian, which the viewer
draws with the unchanged splat renderer by replacing the SH with degree 0 (`rgb_to_sh0`), and what a legend
needs (the scalar behind the colour map, its range, a label with units). `Inspector` ties the modes to an
avatar with the caches they need (feature PCA, offsets per code, sensitivity per code and direction, the kNN
graph) and turns `InspectSettings` into what to upload and draw (`InspectFrame`); the window and
`npga-view render --mode` both go through it.

Definitions (N Gaussians; ranges for colour maps are robust: 1st..99th percentile unless fixed):

- features: the canonical f (N, F) projected on its first three principal components (fitted once on the
  canonical f, signs fixed), each mapped from its 1..99 percentile range to [0, 1] as R, G, B.
- feature:K: channel K of f through a colour map (coolwarm, symmetric about 0, when the channel takes both
  signs; else viridis). latent / latent:K: the same for h (PCA fitted on the canonical h, applied to the posed
  h = h + delta_h of G).
- offset: position offset magnitude ||delta_mu|| of F, G or their sum (world units); of G: opacity (signed
  logit offset), scale (||delta log s||), rotation (angle of the rotation offset, degrees), colour (RGB change of
  the view-independent colour, ||SH_C0 delta_sh0||).
- laplacian: the paper's per-Gaussian smoothness term R_lap(x)_i = ||mean_{j in N(i)} x_j - x_i||^2 on the
  canonical kNN graph, for x = f, for all of G's offsets (concatenated) or one of G's blocks.
- sensitivity: ||d mu_i / d s_k||, how far Gaussian i moves per standard deviation along PCA direction k of the
  expression space, i.e. the norm of the Jacobian-vector product of (F + G_position) with std_k * basis_k,
  computed exactly by forward-mode differentiation through the MLPs (`mlp_jvp`) at the current code.
- opacity: the posed opacity in [0, 1]. scale: size = largest axis of the posed scales (1 sigma, world units),
  or anisotropy = largest / smallest axis. depth: camera-space z of the centre (world units).

Counts: total; in the frustum (centre projects inside the image, in front of the near plane); drawn (what the
renderer's pre-pass keeps, `SplatRenderer.drawn_count`); per body part from `cloud.part_ids`.

Filters: a visibility mask (histogram range with "filter", clipping box or plane) is applied by setting the
opacity of hidden Gaussians to 0 before upload (they are then culled by the pre-pass), so indices stay the
same for picking and for kNN lines; "highlight" instead draws the out-of-range Gaussians grey and faint.
"""

from __future__ import annotations

import time
from dataclasses import astuple, dataclass
from typing import cast

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.inspection.colouring import Colouring, FeaturePCA, pca_colouring, robust_range, scalar_colouring
from npga_core.inspection.graph import edge_lengths, edges_touching, knn_cached, knn_edges, laplacian_terms
from npga_core.inspection.measures import (
    SCALE_MEASURES,
    Counts,
    clip_box,
    clip_plane,
    count_gaussians,
    depth_values,
    histogram,
    in_range,
    recolour,
    scale_values,
)
from npga_core.inspection.sensitivity import expression_direction, position_jvp
from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import Offsets
from npga_core.model.gaussians import SH_C0, GaussianCloud, PosedGaussians

# --- offsets ---------------------------------------------------------------------------------------------------
#: Offset sources of NPGA's networks ("sum" of all, or one network by name; other avatars name theirs).
OFFSET_SOURCES: tuple[str, ...] = ("sum", "F", "G")
OFFSET_ATTRIBUTES: tuple[str, ...] = ("position", "rotation", "scale", "opacity", "colour")
_PLURAL = {"position": "positions", "rotation": "rotations", "scale": "scales", "opacity": "opacities",
           "sh": "colours", "latent": "latent features"}


def offsets_to_numpy(off: Offsets) -> dict[str, np.ndarray]:
    """Offsets as float32 arrays keyed "network.attribute" ("F.position", "G.sh", "exp_deform.position")."""
    return {f"{net}.{attr}": np.asarray(t.detach().numpy(), np.float32)
            for net, blocks in off.by_network.items() for attr, t in blocks.items()}


def _qualified(off: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Keys as "network.attribute"; the short forms "F" (F's position) and "attribute" (G's) are accepted."""
    return {("F.position" if k == "F" else k if "." in k else f"G.{k}"): v for k, v in off.items()}


def offset_sources(off: dict[str, np.ndarray], attribute: str) -> list[str]:
    """The sources an attribute's offset can be shown from: "sum", then each network that offsets it."""
    key = "sh" if attribute == "colour" else attribute
    return ["sum"] + [k.split(".")[0] for k in _qualified(off) if k.split(".", 1)[1] == key]


def offset_values(off: dict[str, np.ndarray], attribute: str = "position", source: str = "sum") -> np.ndarray:
    """The `offset` mode's scalar per Gaussian (see the module docstring); ValueError if it does not exist."""
    if attribute not in OFFSET_ATTRIBUTES:
        raise ValueError(f"unknown offset attribute {attribute!r}; choose from {', '.join(OFFSET_ATTRIBUTES)}")
    off = _qualified(off)
    nets = sorted({k.split(".")[0] for k in off}, key=list(dict.fromkeys(k.split(".")[0] for k in off)).index)
    if source != "sum" and source not in nets:
        raise ValueError(f"unknown offset source {source!r}; choose from {', '.join(['sum', *nets])}")
    key = "sh" if attribute == "colour" else attribute
    parts = [v for k, v in off.items() if k.split(".", 1)[1] == key and (source == "sum" or k.split(".")[0] == source)]
    if not parts:
        if source != "sum":
            has = [_PLURAL[k.split(".", 1)[1]] for k in off if k.split(".")[0] == source]
            raise ValueError(f"{source} only offsets {' and '.join(has)}; choose another network for the {attribute}")
        raise ValueError(f"no network of this avatar predicts a {attribute} offset")
    width = max(p.shape[1] for p in parts)
    d = np.zeros((len(parts[0]), width), np.float64)
    for p in parts:
        d[:, : p.shape[1]] += p
    if attribute == "position":
        return np.linalg.norm(d, axis=1).astype(np.float32)
    if attribute == "opacity":
        return d[:, 0].astype(np.float32)
    if attribute == "scale":
        return np.linalg.norm(d, axis=1).astype(np.float32)
    if attribute == "rotation":  # a rotation offset d acts as the unit quaternion normalize((1,0,0,0) + d)
        q = d + np.array([1.0, 0.0, 0.0, 0.0])
        w = np.abs(q[:, 0]) / np.maximum(np.linalg.norm(q, axis=1), 1e-12)
        return np.degrees(2.0 * np.arccos(np.clip(w, 0.0, 1.0))).astype(np.float32)
    return np.linalg.norm(SH_C0 * d[:, :3], axis=1).astype(np.float32)  # colour: DC coefficients only


def offset_label(attribute: str, source: str, sources: list[str] | None = None) -> str:
    """The legend of the `offset` mode; `sources` (the offsets' sources, e.g. F and G, or a rig) name the sum."""
    names = [n for n in (sources or ["F", "G"]) if n != "sum"]
    who = " + ".join(names) if source == "sum" else source
    return {
        "position": f"|position offset| of {who} (world units)",
        "rotation": f"rotation offset of {who} (degrees; (1,0,0,0) + d as a rotation)",
        "scale": f"|log-scale offset| of {who}",
        "opacity": f"opacity offset of {who} (logit)",
        "colour": f"|colour offset| of {who} (RGB)",
    }[attribute]


def laplacian_values(x: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """The `laplacian` mode's scalar: the paper's R_lap(x)_i on the graph `nbrs` (N,) float32."""
    return laplacian_terms(x, nbrs).astype(np.float32)


# --- settings and the per-avatar controller -----------------------------------------------------------------
COLOUR_MODES: tuple[str, ...] = ("rgb", "features", "feature:K", "latent", "latent:K", "offset", "laplacian",
                                 "sensitivity", "opacity", "scale", "depth")
STYLES: tuple[str, ...] = ("splats", "points", "ellipsoids")
KNN_SHOW: tuple[str, ...] = ("off", "all", "picked", "selection")
KNN_COLOURS: tuple[str, ...] = ("length", "feature", "stretch")
HIST_ACTIONS: tuple[str, ...] = ("off", "highlight", "filter")
CLIP_MODES: tuple[str, ...] = ("off", "box", "plane")
PICK_COLOUR = (1.0, 0.85, 0.1)


def parse_mode(mode: str) -> tuple[str, int | None]:
    """'feature:3' -> ('feature', 3); 'latent' -> ('latent', None); ValueError for unknown modes."""
    name, _, arg = mode.partition(":")
    if name in ("feature", "latent") and arg:
        try:
            return name, int(arg)
        except ValueError:
            raise ValueError(f"mode {mode!r}: the channel after ':' must be an integer") from None
    if arg or mode not in COLOUR_MODES:
        raise ValueError(f"unknown colour mode {mode!r}; choose from {', '.join(COLOUR_MODES)}")
    return name, None


@dataclass
class InspectSettings:
    """What the inspection shows; written by the Inspect panel and the `render` command, read by `Inspector`."""

    mode: str = "rgb"  # one of COLOUR_MODES, with K filled in ("feature:3")
    cmap: str = ""  # colour map; "" = the mode's default
    value_range: tuple[float, float] | None = None  # fixed legend range; None = robust 1..99 percentiles
    offset_source: str = "sum"  # F | G | sum (position only)
    offset_attr: str = "position"  # one of OFFSET_ATTRIBUTES
    laplacian_of: str = "features"  # features | G | a G block (position, rotation, scale, opacity, sh, latent)
    direction: int = 0  # sensitivity: PCA direction, 0-based
    scale_measure: str = "size"  # size | anisotropy
    style: str = "splats"  # one of STYLES
    point_px: float = 2.0  # radius of the discs of the points style
    knn_show: str = "off"  # one of KNN_SHOW
    knn_k: int = 8
    knn_colour: str = "length"  # one of KNN_COLOURS
    hist_attr: str = "opacity"  # see `Inspector.attribute_values`
    hist_range: tuple[float, float] | None = None
    hist_action: str = "off"  # one of HIST_ACTIONS
    clip: str = "off"  # one of CLIP_MODES
    clip_lo: tuple[float, float, float] = (-1.0, -1.0, -1.0)
    clip_hi: tuple[float, float, float] = (1.0, 1.0, 1.0)
    clip_point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    clip_normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    picked: int | None = None  # the inspected Gaussian
    pick_on_click: bool = False  # left click in the view picks instead of orbiting

    def key(self) -> tuple:
        """Changes whenever anything here changes (the app recomputes the frame then)."""
        return astuple(self)


@dataclass
class LineSet:
    """Segments between rows of `positions`, one colour per edge."""

    positions: np.ndarray  # (M, 3) float32
    edges: np.ndarray  # (E, 2) int32
    colours: np.ndarray  # (E, 4) float32 RGBA, straight (not premultiplied)


@dataclass
class InspectFrame:
    """What to draw for one pose: upload `posed`, draw with `style`, lines over the splats."""

    posed: PosedGaussians
    style: str
    point_px: float
    colouring: Colouring | None
    lines: LineSet | None


@dataclass
class InspectInfo:
    """What the Inspect panel shows (filled by the app each time the frame or the camera changes)."""

    colouring: Colouring | None = None
    counts: Counts | None = None
    hist_counts: np.ndarray | None = None
    hist_edges: np.ndarray | None = None
    hist_in_range: int = 0
    record: dict | None = None  # `Inspector.record` of the picked Gaussian
    knn_ms: float = 0.0  # time of the last kNN graph computation (0 when it came from the cache)
    knn_edges: int = 0  # edges drawn
    error: str | None = None  # why the mode could not be shown


class Inspector:
    """The colour modes, counts, histograms and kNN lines of one avatar, with their caches.

    Offsets are computed in-process by `Avatar.offsets` and cached for the last code; sensitivity per (code,
    direction); the kNN graph per k (`graph.knn_cached`); feature and latent PCAs once.
    """

    def __init__(self, avatar: Avatar) -> None:
        self.avatar = avatar
        self._pca: dict[str, FeaturePCA] = {}
        self._offsets: tuple[bytes, dict[str, np.ndarray]] | None = None
        self._sensitivity: dict[tuple[bytes, int], np.ndarray] = {}
        self.knn_ms = 0.0

    @property
    def cloud(self) -> GaussianCloud:
        return self.avatar.cloud

    # -- cached inputs ---------------------------------------------------------------------------------------
    def _code(self, code: np.ndarray | None) -> np.ndarray:
        return self.avatar.neutral_code() if code is None else self.avatar.check_code(code)

    def pca(self, name: str) -> FeaturePCA:
        """PCA of the canonical "features" (f) or "latent" (h), fitted once."""
        if name not in self._pca:
            x = self.cloud.features if name == "features" else self.cloud.latent
            if x is None or x.shape[1] == 0:
                raise ValueError(f"the avatar has no {'features f' if name == 'features' else 'latent features h'}")
            self._pca[name] = FeaturePCA.fit(x)
        return self._pca[name]

    def offsets(self, code: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """`offsets_to_numpy(avatar.offsets(code))`, cached for the last code."""
        if self.avatar.dynamics is None:
            raise ValueError("this avatar has no dynamics (no offsets)")
        z = self._code(code)
        if self._offsets is None or self._offsets[0] != z.tobytes():
            self._offsets = (z.tobytes(), offsets_to_numpy(self.avatar.offsets(z)))
        return self._offsets[1]

    def sensitivity(self, code: np.ndarray | None, k: int) -> np.ndarray:
        """||d mu / d s_k|| per Gaussian (world units per standard deviation), cached per (code, k)."""
        z = self._code(code)
        key = (z.tobytes(), int(k))
        if key not in self._sensitivity:
            if len(self._sensitivity) > 8:
                self._sensitivity.clear()
            jvp = position_jvp(self.avatar, z, expression_direction(self.avatar, k))
            self._sensitivity[key] = np.linalg.norm(jvp, axis=1).astype(np.float32)
        return self._sensitivity[key]

    def graph(self, k: int) -> np.ndarray:
        """kNN graph (N, k) of the canonical centres (cached); `knn_ms` says how long it took."""
        t0 = time.perf_counter()
        nbrs = knn_cached(self.cloud.means, int(k))
        self.knn_ms = (time.perf_counter() - t0) * 1e3
        return nbrs

    # -- colours ---------------------------------------------------------------------------------------------
    def colouring(self, settings: InspectSettings, posed: PosedGaussians, code: np.ndarray | None = None,
                  camera: Camera | None = None) -> Colouring | None:
        """The colours of `settings.mode` (None for "rgb"); ValueError when the avatar lacks what it needs."""
        name, channel = parse_mode(settings.mode)
        s = settings
        if name == "rgb":
            return None
        if name in ("features", "latent") and channel is None:
            x = self.cloud.features if name == "features" else posed.latent
            if x is None:
                raise ValueError("the avatar has no latent features h")
            return pca_colouring(x, self.pca(name), "f" if name == "features" else "h")
        if name in ("feature", "latent"):
            assert channel is not None  # parse_mode gives these names only with a channel
            x = self.cloud.features if name == "feature" else posed.latent
            if x is None or not 0 <= channel < x.shape[1]:
                width = 0 if x is None else x.shape[1]
                raise ValueError(f"no {name} channel {channel}; the avatar has {width}")
            label = f"{'f' if name == 'feature' else 'h'}[{channel}]"
            lo, hi = robust_range(x[:, channel])
            signed = lo < 0.0 < hi  # signed channels: diverging map, symmetric about 0
            return scalar_colouring(x[:, channel], label, s.cmap or ("coolwarm" if signed else "viridis"),
                                    s.value_range, symmetric=signed)
        if name == "offset":
            off = self.offsets(code)
            v = offset_values(off, s.offset_attr, s.offset_source)
            signed = s.offset_attr == "opacity"
            rng = s.value_range or (robust_range(v, symmetric=True) if signed else (0.0, robust_range(v)[1]))
            return scalar_colouring(v, offset_label(s.offset_attr, s.offset_source,
                                                    offset_sources(off, s.offset_attr)),
                                    s.cmap or ("coolwarm" if signed else "viridis"), rng)
        if name == "laplacian":
            nbrs = self.graph(s.knn_k)
            x, label = self._laplacian_input(s.laplacian_of, code)
            v = laplacian_values(x, nbrs)
            return scalar_colouring(v, f"R_lap of {label} (k = {s.knn_k})", s.cmap or "viridis",
                                    s.value_range or (0.0, robust_range(v)[1]))
        if name == "sensitivity":
            v = self.sensitivity(code, s.direction)
            channels = self.avatar.slider_channels
            label = (f"|d mu / d {channels[s.direction]}| (world units per unit weight)"
                     if channels is not None and s.direction < len(channels)
                     else f"|d mu / d PC {s.direction + 1}| (world units per std)")
            return scalar_colouring(v, label, s.cmap or "viridis",
                                    s.value_range or (0.0, robust_range(v)[1]))
        if name == "opacity":
            return scalar_colouring(posed.opacities, "opacity", s.cmap or "viridis", s.value_range or (0.0, 1.0))
        if name == "scale":
            v = scale_values(posed.scales, s.scale_measure)
            label = "largest scale (1 sigma, world units)" if s.scale_measure == "size" else "anisotropy (max / min)"
            return scalar_colouring(v, label, s.cmap or "viridis", s.value_range)
        if camera is None:
            raise ValueError("the depth mode needs a camera")
        v = depth_values(posed.means, camera)
        front = v > 0
        rng = s.value_range or robust_range(v[front] if front.any() else v)
        return scalar_colouring(v, "camera depth (world units)", s.cmap or "turbo_r", rng)

    def _laplacian_input(self, what: str, code: np.ndarray | None) -> tuple[np.ndarray, str]:
        if what == "features":
            if self.cloud.feature_dim == 0:
                raise ValueError("the avatar has no features f")
            return np.asarray(self.cloud.features), "f"
        off = self.offsets(code)
        nets = {k.split(".")[0] for k in off}
        if what in nets:
            blocks = [v for k, v in off.items() if k.split(".")[0] == what]
            return np.concatenate(blocks, axis=1), f"all offsets of {what}"
        if f"G.{what}" not in off:
            raise ValueError(f"G predicts no {what!r} offset; choose features, a network ({', '.join(sorted(nets))})"
                             f" or one of {', '.join(k[2:] for k in off if k.startswith('G.'))}")
        return off[f"G.{what}"], f"G's {what} offset"

    # -- values for histograms and range filters ---------------------------------------------------------------
    def attribute_names(self) -> list[str]:
        """Names `attribute_values` accepts for this avatar."""
        names = ["opacity", "size", "anisotropy"]
        names += [f"feature:{k}" for k in range(self.cloud.feature_dim)]
        names += [f"latent:{k}" for k in range(self.cloud.latent_dim)]
        if self.avatar.dynamics is not None:
            names += ["offset", "offset:F", "offset:G"]
        return names

    def attribute_values(self, name: str, posed: PosedGaussians, code: np.ndarray | None = None) -> np.ndarray:
        """opacity, size, anisotropy (posed), feature:K (f), latent:K (posed h), offset[:F|:G] (position offset
        magnitude of the sum, F or G at the code) per Gaussian (N,) float32."""
        if name == "opacity":
            return np.asarray(posed.opacities, np.float32)
        if name in SCALE_MEASURES:
            return scale_values(posed.scales, name)
        kind, _, arg = name.partition(":")
        if kind in ("feature", "latent"):
            x = self.cloud.features if kind == "feature" else posed.latent
            if x is None or not arg.isdigit() or int(arg) >= x.shape[1]:
                raise ValueError(f"no attribute {name!r}")
            return np.asarray(x[:, int(arg)], np.float32)
        if kind == "offset":
            return offset_values(self.offsets(code), "position", arg or "sum")
        raise ValueError(f"unknown attribute {name!r}; choose from {', '.join(self.attribute_names())}")

    # -- the frame ---------------------------------------------------------------------------------------------
    def visibility(self, settings: InspectSettings, posed: PosedGaussians, code: np.ndarray | None = None
                   ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(visible mask or None, highlight mask or None) from the histogram range and the clipping."""
        s = settings
        visible = highlight = None
        if s.hist_action != "off" and s.hist_range is not None:
            inside = in_range(self.attribute_values(s.hist_attr, posed, code), *s.hist_range)
            if s.hist_action == "filter":
                visible = inside
            else:
                highlight = inside
        if s.clip != "off":
            kept = (clip_box(posed.means, s.clip_lo, s.clip_hi) if s.clip == "box"
                    else clip_plane(posed.means, s.clip_point, s.clip_normal))
            visible = kept if visible is None else visible & kept
        return visible, highlight

    def lines(self, settings: InspectSettings, posed: PosedGaussians, selection: np.ndarray | None = None
              ) -> LineSet | None:
        """kNN edges between posed centres (all, around the picked Gaussian, or touching `selection`)."""
        s = settings
        picked = s.picked if s.picked is not None and 0 <= s.picked < len(posed) else None
        if s.knn_show == "off" and picked is None:
            return None
        nbrs = self.graph(s.knn_k)
        pos = np.asarray(posed.means, np.float32)
        parts: list[tuple[np.ndarray, np.ndarray]] = []
        if s.knn_show == "all" or (s.knn_show == "selection" and selection is not None):
            edges = knn_edges(nbrs)
            if s.knn_show == "selection":
                edges = edges_touching(edges, cast(np.ndarray, selection))
            parts.append((edges, self.edge_colours(s.knn_colour, edges, pos)))
        if picked is not None:  # the picked Gaussian's own k neighbours, in the pick colour
            edges = np.stack([np.full(nbrs.shape[1], picked), nbrs[picked]], axis=1).astype(np.int32)
            parts.append((edges, np.tile([*PICK_COLOUR, 1.0], (len(edges), 1)).astype(np.float32)))
        if not parts:  # "picked" or "selection" with nothing picked or selected
            return None
        edges = np.concatenate([p[0] for p in parts]).astype(np.int32)
        colours = np.concatenate([p[1] for p in parts]).astype(np.float32)
        if picked is not None:  # a 3D cross on the picked Gaussian, 3 sigma of its largest axis
            r = 3.0 * float(np.max(posed.scales[picked]))
            cross = pos[picked] + r * np.concatenate([np.eye(3), -np.eye(3)]).astype(np.float32)
            base = len(pos)
            pos = np.concatenate([pos, cross])
            edges = np.concatenate([edges, [[base + i, base + i + 3] for i in range(3)]]).astype(np.int32)
            colours = np.concatenate([colours, np.tile([*PICK_COLOUR, 1.0], (3, 1))]).astype(np.float32)
        return LineSet(pos, edges, colours)

    def edge_colouring(self, by: str, edges: np.ndarray, posed_means: np.ndarray) -> Colouring:
        """Colours of edges (and their legend): viridis of the canonical length, of ||f_i - f_j||, or coolwarm of
        the stretch, posed / canonical length, around 1."""
        canonical = edge_lengths(self.cloud.means, edges)
        if by == "length":
            return scalar_colouring(canonical, "kNN edge length (canonical, world units)")
        if by == "feature":
            f = np.asarray(self.cloud.features, np.float32)
            return scalar_colouring(np.linalg.norm(f[edges[:, 0]] - f[edges[:, 1]], axis=1), "kNN edge |f_i - f_j|")
        if by == "stretch":
            ratio = edge_lengths(posed_means, edges) / np.maximum(canonical, 1e-12)
            m = max(robust_range(np.abs(ratio - 1.0))[1], 1e-6)
            return scalar_colouring(ratio, "kNN edge stretch (posed / canonical)", "coolwarm", (1.0 - m, 1.0 + m))
        raise ValueError(f"unknown edge colouring {by!r}; choose from {', '.join(KNN_COLOURS)}")

    def edge_colours(self, by: str, edges: np.ndarray, posed_means: np.ndarray) -> np.ndarray:
        """RGBA (E, 4) of `edge_colouring`."""
        rgb = self.edge_colouring(by, edges, posed_means).rgb
        return np.concatenate([rgb, np.ones((len(edges), 1), np.float32)], axis=1)

    def frame(self, settings: InspectSettings, posed: PosedGaussians, code: np.ndarray | None = None,
              camera: Camera | None = None, selection: np.ndarray | None = None) -> InspectFrame:
        """Colours, visibility and lines of a posed cloud under `settings` (see the module docstring)."""
        colouring = self.colouring(settings, posed, code, camera)
        visible, highlight = self.visibility(settings, posed, code)
        rgb = None if colouring is None else colouring.rgb
        out = posed if rgb is None and visible is None and highlight is None else recolour(posed, rgb, visible,
                                                                                            highlight)
        return InspectFrame(out, settings.style, settings.point_px, colouring, self.lines(settings, posed, selection))

    @staticmethod
    def camera_dependent(settings: InspectSettings) -> bool:
        """Whether the frame must be rebuilt when only the camera moves (the depth mode)."""
        return settings.mode == "depth"

    def info(self, settings: InspectSettings, posed: PosedGaussians, code: np.ndarray | None = None,
             colouring: Colouring | None = None, camera: Camera | None = None, drawn: np.ndarray | int | None = None,
             near: float = 0.01, bins: int = 64) -> InspectInfo:
        """What the Inspect panel shows: the legend (`colouring` of the frame), counts (with a camera), the
        histogram of `settings.hist_attr` over its min..max, the record of the picked Gaussian. A problem with
        one of them goes to `error` and leaves it empty."""
        out = InspectInfo(colouring=colouring, knn_ms=self.knn_ms)
        if camera is not None:
            out.counts = self.counts(camera, posed, drawn, near)
        try:
            values = self.attribute_values(settings.hist_attr, posed, code)
            out.hist_counts, out.hist_edges = histogram(values, bins)
            if settings.hist_range is not None:
                out.hist_in_range = int(in_range(values, *settings.hist_range).sum())
        except ValueError as exc:
            out.error = str(exc)
        if settings.picked is not None:
            try:
                out.record = self.record(settings.picked, posed, code, settings.knn_k)
            except ValueError as exc:
                out.error = str(exc)
        return out

    def counts(self, camera: Camera, posed: PosedGaussians, drawn: np.ndarray | int | None = None,
               near: float = 0.01) -> Counts:
        """`count_gaussians` with the avatar's parts."""
        return count_gaussians(camera, posed.means, self.cloud.part_ids, self.cloud.part_names, drawn, near)

    def record(self, index: int, posed: PosedGaussians, code: np.ndarray | None = None, k: int = 8) -> dict:
        """Everything about Gaussian `index`: canonical and posed attributes, f, h, offsets, neighbours."""
        c = self.cloud
        if not 0 <= index < len(c):
            raise ValueError(f"no Gaussian {index}; the avatar has {len(c)}")
        rec: dict = {"index": int(index), "canonical": _attributes(c.posed_static(), index),
                     "posed": _attributes(posed, index),
                     "features": np.asarray(c.features[index]).copy()}
        rec["latent"] = None if c.latent is None else np.asarray(c.latent[index]).copy()
        rec["posed_latent"] = None if posed.latent is None else posed.latent[index].copy()
        if c.part_ids is not None and 0 <= int(c.part_ids[index]) < len(c.part_names):
            rec["part"] = c.part_names[int(c.part_ids[index])]
        rec["offsets"] = {}
        if self.avatar.dynamics is not None:
            rec["offsets"] = {k_.replace(".", " "): v[index].copy() for k_, v in self.offsets(code).items()}
        nbrs = self.graph(k)[index]
        d = np.linalg.norm(np.asarray(c.means)[nbrs] - np.asarray(c.means)[index], axis=1)
        rec["neighbours"] = [(int(j), float(dist)) for j, dist in zip(nbrs, d, strict=True)]
        return rec


def _attributes(p: PosedGaussians, i: int) -> dict:
    """Activated attributes of Gaussian i (colour: the view-independent DC colour)."""
    return {"position": p.means[i].copy(), "rotation": p.quats[i].copy(), "scale": p.scales[i].copy(),
            "opacity": float(p.opacities[i]), "colour": np.clip(p.sh[i, 0] * SH_C0 + 0.5, 0.0, 1.0)}
