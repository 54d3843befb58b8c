"""npga_core: the NPGA avatar model, its file formats and maths (numpy + torch, no GL, no UI).

The names users import are available from here (loaded on first use, so ``import npga_core`` stays fast):
``from npga_core import load_avatar, save_avatar, ExpressionSequence``.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = {
    "Avatar": "npga_core.model.avatar",
    "GaussianCloud": "npga_core.model.gaussians",
    "PosedGaussians": "npga_core.model.gaussians",
    "Dynamics": "npga_core.model.dynamics",
    "ExpressionSpace": "npga_core.model.expression",
    "ScreenCNN": "npga_core.model.cnn",
    "make_synthetic_avatar": "npga_core.model.synthetic",
    "load_avatar": "npga_core.files.loading",
    "load_sequence": "npga_core.files.loading",
    "DEMO_AVATAR": "npga_core.files.loading",
    "save_avatar": "npga_core.files.checkpoint",
    "read_ply": "npga_core.files.ply",
    "save_posed_ply": "npga_core.files.ply",
    "ExpressionSequence": "npga_core.files.sequences",
    "load_rig": "npga_core.files.rig",
    "AvatarFileError": "npga_core.errors",
    "Camera": "npga_core.camera.cameras",
    "OrbitCamera": "npga_core.camera.orbit",
    "PoseEngine": "npga_core.posing.engine",
    "Inspector": "npga_core.inspection.inspector",
    "EditSession": "npga_core.editing.edits",
    "KeyframeTimeline": "npga_core.editing.keyframes",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> object:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'npga_core' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
