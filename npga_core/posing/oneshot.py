"""Exact poses for the command line (`render`, `export`) in the precision asked for with `--precision`.

float32 keeps the earlier path (`Avatar.pose`: its output is unchanged); bfloat16, asked for or taken by "auto"
where the CPU multiplies it natively and the fidelity check passes, poses through `FastPoser`.
"""

from __future__ import annotations

import numpy as np

from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.fastpose import FastPoser, posed_buffers
from npga_core.posing.precision import check_precision


class ExactPoses:
    """`pose(code)` of one avatar in the chosen precision; `precision` says which runs ("fp32" or "bf16")."""

    def __init__(self, avatar: Avatar, precision: str | None = "auto", threads: int = 2):
        requested = check_precision(precision)
        self.avatar, self.poser, self.precision = avatar, None, "fp32"
        if avatar.dynamics is not None and len(avatar) and requested != "fp32":
            poser = FastPoser(avatar, threads=threads, precision=requested)
            if poser.precision == "bf16":
                self.poser, self.precision = poser, "bf16"

    def pose(self, code: np.ndarray | None = None) -> PosedGaussians:
        """Posed Gaussians at `code` (None: the mean code), as `Avatar.pose`."""
        if self.poser is None:
            return self.avatar.pose(code)
        a = self.avatar
        dest = posed_buffers(len(a), a.cloud.sh.shape[1], a.cloud.latent_dim)
        self.poser.pose_into(a.neutral_code() if code is None else code, dest)
        return PosedGaussians(**dest)
