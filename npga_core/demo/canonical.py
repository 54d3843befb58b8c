"""The canonical Gaussian cloud of the demo: surface samples -> discs with colours, features and parts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from npga_core.demo.colors import albedo, bake_lighting, cavity, colours_to_sh
from npga_core.demo.ict import PART_NAMES, IctHead
from npga_core.demo.sampling import SurfaceSamples, disc_attributes, sample_surface
from npga_core.model.gaussians import GaussianCloud, logit

FEATURE_DIM = 8


@dataclass
class CanonicalBuild:
    """The canonical cloud with what later steps need: the samples, tangent frames and DC colours."""

    cloud: GaussianCloud
    samples: SurfaceSamples
    frames: np.ndarray  # (N, 3, 3) columns: tangent 1, tangent 2, normal
    colour: np.ndarray  # (N, 3) baked colour seen head-on
    facing: float  # share of the colour that fades towards grazing views (degree-1 SH)


def build_canonical(head: IctHead, n_gaussians: int, rng: np.random.Generator, disc_size: float = 0.75,
                    thickness: float = 0.12, opacity: float = 0.98, facing: float = 0.22) -> CanonicalBuild:
    """Sample the surfaces and make the canonical cloud (features zero: `features.init_features` fills them)."""
    samples = sample_surface(head, n_gaussians, rng)
    quats, log_scales, frames = disc_attributes(samples, disc_size, thickness)
    base = albedo(head, samples, rng)
    # teeth sit in the deepest cavity of all; halve their occlusion so they stay white
    strength = np.where(samples.part == PART_NAMES.index("teeth"), 0.5, 1.0)
    colour = bake_lighting(base, samples.normals, cavity(samples.points, samples.normals), occlusion_strength=strength)
    colour = colour.astype(np.float32)
    n = len(samples)
    cloud = GaussianCloud(
        means=samples.points.astype(np.float32),
        quats=quats,
        log_scales=log_scales,
        opacity_logits=np.full(n, logit(np.array(opacity)), np.float32),
        sh=colours_to_sh(colour, samples.normals, facing),
        features=np.zeros((n, FEATURE_DIM), np.float32),
        part_ids=samples.part.astype(np.int16),
        part_names=list(PART_NAMES),
    )
    return CanonicalBuild(cloud, samples, frames, colour, facing)
