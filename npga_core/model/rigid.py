"""The tracked rigid head transform applied to posed Gaussians (the last step of posing a tracked frame)."""

from __future__ import annotations

import numpy as np

from npga_core.model.gaussians import PosedGaussians
from npga_core.model.rotations import quat_from_matrix, quat_product, similarity_parts
from npga_core.model.sh import rotate_sh


def transform_posed(posed: PosedGaussians, transform: np.ndarray) -> PosedGaussians:
    """The Gaussians moved by `transform` (4x4, s R with s > 0, plus t; canonical -> world): centres
    (x' = s R x + t), rotations (q' = q_R q), scales (times s) and the SH turned with the head."""
    m = np.asarray(transform, np.float64)
    s, r, _ = similarity_parts(m)
    if not s > 0:
        raise ValueError("a head transform must be a scaled rotation (positive determinant)")
    q = quat_product(quat_from_matrix(r), posed.quats)
    means = np.asarray(posed.means, np.float64) @ m[:3, :3].T + m[:3, 3]
    return PosedGaussians(means.astype(np.float32), q.astype(np.float32),
                          (s * np.asarray(posed.scales, np.float64)).astype(np.float32), posed.opacities,
                          rotate_sh(posed.sh, r), posed.latent)
