"""Gaussian-Head-Avatar (GHA, YuelangX/Gaussian-Head-Avatar, CVPR 2024) checkpoints as avatars.

GHA saves `gaussianhead_latest` (the state dict of its `GaussianHeadModule`) and `supres_latest` (its
`SuperResolutionModule`) with `torch.save`; they are read here with `torch.load(weights_only=True)` only, so
nothing in them is ever executed. What GHA's `generate()` does (lib/module/GaussianHeadModule.py, at commit
d006861 of 2024-07-12) is described as data (`npga_core.model.networks`), not copied:

- six MLPs (lib/network/MLP.py: 1x1 Conv1d layers, leaky ReLU between them, the input re-appended after the
  hidden vector at layer ``int(len(dims) / 2)``), with tanh on the two deformation networks;
- inputs: tanh of the per-Gaussian features, the expression coefficients, the positional encoding
  (lib/network/PositionalEmbedding.py: x, sin(2^k x), cos(2^k x), k < pos_freq) of the canonical position and of
  the 6-D head pose (axis-angle, translation), the second per-frame condition;
- per-Gaussian blend weights from the squared distance d2 to the nearest neutral landmark (pytorch3d's
  `knn_points` returns squared distances): w_exp = clamp((far - d2) / (far - near), 0, 1), w_pose = 1 - w_exp,
  static, so they are baked here and the Gaussians sorted into near, blended and far groups (also the parts);
- composition: xyz + deform_scale * sum, log scales / rotations / opacity logits + attributes_scale * sum
  (rotation normalised per Gaussian; before 2024-07-12 across the Gaussians: `legacy_rotation`), 32 colour
  channels from zero (the first three are the image; as SH DC here);
- the rigid head transform x' = s R x + t (R from the pose's axis-angle) is a sequence's head pose
  (`read_gha_params`), applied like every tracker's.

The super-resolution network (lib/network/Upsampler.py) becomes a version-2 CNN description.
"""

from __future__ import annotations

import pickle
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import torch

from npga_core.errors import AvatarFileError
from npga_core.files.pose import similarity_pose
from npga_core.files.sequences import DEFAULT_FPS, ExpressionSequence
from npga_core.files.untrusted import (
    MAX_LOG_SCALE,
    MAX_POSITION,
    MAX_QUAT,
    bounded_floats,
    is_folder,
    open_regular,
    read_bytes,
    read_npz,
    regular_file,
    shown,
)
from npga_core.model.avatar import Avatar
from npga_core.model.cnn import CNNConfig, ScreenCNN
from npga_core.model.dynamics import ConditionedMLP, Dynamics
from npga_core.model.expression import ExpressionSpace
from npga_core.model.gaussians import SH_C0, GaussianCloud
from npga_core.model.networks import InputSpec, MLPConfig, Route
from npga_core.schema import SchemaError, decode, number

HEAD = "gaussianhead_latest"
SUPRES = "supres_latest"
MAX_CHECKPOINT_BYTES = 4 * 2**30
MAX_GAUSSIANS = 5_000_000
#: Most records in a checkpoint archive; largest magnitude of any stored value (as the .npga reader's).
MAX_RECORDS = 4096
MAX_LANDMARKS = 1024
MAX_PARAMETER = 1e8
_INT_DTYPES = (torch.int8, torch.uint8, torch.int16, torch.int32, torch.int64, torch.bool)
#: Range of each per-Gaussian tensor of the head checkpoint (positions in metres, log-scales, quaternions, logits).
_RANGES = {"xyz": MAX_POSITION, "scales": MAX_LOG_SCALE, "rotation": MAX_QUAT, "opacity": 1e4}
#: The values of GHA's own training configs (config/train_gaussianhead_N031.yaml, reenactment_N031.yaml); its
#: config.py defaults (far 0.2, attributes_scale 0.05) are overridden by every config it ships.
PUBLISHED = {"dist_threshold_near": 0.1, "dist_threshold_far": 0.25, "deform_scale": 0.3, "attributes_scale": 0.2}
CONFIG_SOURCE = "GHA's published training config (config/train_gaussianhead_N031.yaml)"
NETWORKS = ("exp_color", "pose_color", "exp_attributes", "pose_attributes", "exp_deform", "pose_deform")
PART_NAMES = ["near (expression only)", "blended", "far (pose only)"]
CONDITION = {"dim": 6, "kind": "gha_head_pose",
             "description": "Gaussian-Head-Avatar's head pose as its networks take it: axis-angle (3) then "
                            "translation (3), the 'pose' row of params.npz"}


def is_gha_folder(path: str | Path) -> bool:
    """True when `path` is a folder holding GHA's `gaussianhead_latest`."""
    p = Path(path)
    return is_folder(p) and (p / HEAD).exists()


def _check_archive(path: Path, size: int) -> None:
    """A `torch.save` zip archive (the format since torch 1.6, which GHA's checkpoints have) whose records are
    stored as torch writes them: a compressed record could claim gigabytes that torch allocates before
    inflating, and the older pickle-only format sizes its storages from the pickle."""
    try:
        with open_regular(path, "a torch checkpoint") as fh, zipfile.ZipFile(fh) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        raise AvatarFileError(path, "not a torch.save zip archive (only torch's zip format, since torch 1.6, is "
                              "read)") from None
    if len(infos) > MAX_RECORDS:
        raise AvatarFileError(path, f"has {len(infos)} records, more than the {MAX_RECORDS} allowed")
    for info in infos:
        if info.compress_type != zipfile.ZIP_STORED or info.file_size > size:
            raise AvatarFileError(path, f"record {shown(info.filename)[:80]!r} claims {info.file_size} bytes "
                                  f"compressed into {info.compress_size} (torch.save stores records uncompressed)")


def load_state_dict(path: Path, what: str) -> dict[str, torch.Tensor]:
    """A `torch.save`d state dict of tensors, read with `weights_only=True` (anything else refused, one line):
    records stored uncompressed, no tensor claiming more elements than its data holds (an expanded view of a
    few bytes), finite values within +-`MAX_PARAMETER`."""
    regular_file(path, what)
    size = path.stat().st_size
    if size > MAX_CHECKPOINT_BYTES:
        raise AvatarFileError(path, f"is {size} bytes, more than the {MAX_CHECKPOINT_BYTES} a checkpoint may have")
    _check_archive(path, size)
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols it then refuses or reads anyway
            warnings.simplefilter("ignore")
            state = torch.load(path, weights_only=True, map_location="cpu")
    except pickle.UnpicklingError as e:
        first = str(e).strip().splitlines()
        detail = next((ln.strip() for ln in first if "Unsupported" in ln or "global" in ln.lower()), "")
        raise AvatarFileError(path, "holds more than tensors; refused without running it"
                              + (f" ({detail[:160]})" if detail else "")) from None
    except MemoryError:
        raise AvatarFileError(path, "not enough memory to read it") from None
    except (RuntimeError, EOFError, ValueError, OSError, zipfile.BadZipFile, KeyError, TypeError, AttributeError,
            IndexError, OverflowError) as e:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise AvatarFileError(path, f"not a readable torch checkpoint ({msg[:160]})") from None
    if not isinstance(state, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                              for k, v in state.items()):
        raise AvatarFileError(path, "is not a state dict of named tensors")
    for k, v in state.items():
        _check_tensor(path, k, v)
    return {k: v.detach().to(torch.float32) if v.is_floating_point() else v for k, v in state.items()}


def _check_tensor(path: Path, key: str, v: torch.Tensor) -> None:
    need = v.numel() * v.element_size()
    if need > v.untyped_storage().nbytes():
        raise AvatarFileError(path, f"{shown(key)} claims shape {tuple(v.shape)} ({need} bytes) from "
                              f"{v.untyped_storage().nbytes()} bytes of data")
    if v.is_complex() or not (v.is_floating_point() or v.dtype in _INT_DTYPES):
        raise AvatarFileError(path, f"{shown(key)} has dtype {v.dtype}; real numbers are expected")
    if v.is_floating_point() and v.numel():
        if not bool(torch.isfinite(v).all()):
            raise AvatarFileError(path, f"{shown(key)} has NaN/Inf values")
        peak = float(v.abs().max())
        if peak > MAX_PARAMETER:
            raise AvatarFileError(path, f"{shown(key)} reaches {peak:.3g}, beyond the +-{MAX_PARAMETER:g} any "
                                  "trained value has (it would overflow float32 in a forward pass)")


def read_config(path: Path) -> dict[str, float]:
    """The `gaussianheadmodule` numbers of a GHA YAML config (yaml.safe_load: no tags, no code)."""
    import yaml

    text = read_bytes(path, 1 << 20, "a GHA config")
    try:
        cfg = yaml.safe_load(text.decode("utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError, ValueError) as e:  # ValueError: integers of > 4300 digits
        raise AvatarFileError(path, f"not a readable YAML config ({(str(e).splitlines() or [''])[0][:120]})") from None
    except RecursionError:
        raise AvatarFileError(path, "not a readable YAML config (nested too deeply)") from None
    try:
        module = decode(cfg, _Config).gaussianheadmodule
    except SchemaError:
        raise AvatarFileError(path, "has no gaussianheadmodule section (not a GHA config)") from None
    try:
        return {key: float(number(module[key], f"gaussianheadmodule.{key}", -1e6, 1e6))
                for key in (*PUBLISHED, "pos_freq", "exp_coeffs_dim") if key in module}
    except SchemaError as e:
        raise AvatarFileError(path, f"{e} (not a usable number)") from None


class _Config(msgspec.Struct):
    """The part of a GHA YAML config read (its numbers, by `number`)."""

    gaussianheadmodule: dict[str, Any]


def _mlp_dims(state: dict[str, torch.Tensor], name: str, path: Path) -> list[int]:
    """The `dims` list of GHA's MLP `name` from its conv weights, checked against MLP.py's skip rule."""
    convs = sorted(int(m.group(1)) for k in state if (m := re.fullmatch(rf"{name}\.conv(\d+)\.weight", k)))
    if not convs or convs != list(range(len(convs))):
        raise AvatarFileError(path, f"has no layers of the {name} network")
    dims = [int(state[f"{name}.conv0.weight"].shape[1])]
    skip = (len(convs) + 1) // 2  # MLP.py: skip_layer = int(len(dims) / 2), dims has one entry more than layers
    for i in convs:
        w, b = state[f"{name}.conv{i}.weight"], state.get(f"{name}.conv{i}.bias")
        want_in = dims[i] + (dims[0] if i == skip else 0)
        if w.dim() != 3 or w.shape[2] != 1 or w.shape[1] != want_in or b is None or b.shape != (w.shape[0],):
            raise AvatarFileError(path, f"{name}.conv{i} has shape {tuple(w.shape)}, GHA's MLP needs "
                                  f"({'out'}, {want_in}, 1) and a bias")
        dims.append(int(w.shape[0]))
    if len(set(dims[1:-1])) > 1:
        raise AvatarFileError(path, f"{name} has hidden widths {dims[1:-1]}; only equal widths are supported")
    return dims


def _tensor(state: dict, key: str, shape: tuple, path: Path) -> torch.Tensor:
    t = state.get(key)
    if t is None:
        raise AvatarFileError(path, f"has no {key!r} (not a GHA gaussianhead checkpoint)")
    if t.dim() != len(shape) or any(s is not None and t.shape[i] != s for i, s in enumerate(shape)):
        raise AvatarFileError(path, f"{key} has shape {tuple(t.shape)}, expected {shape}")
    return t


def blend_weights(xyz: torch.Tensor, landmarks: torch.Tensor, near: float, far: float) -> torch.Tensor:
    """GHA's expression weight per Gaussian (float32, as generate() computes it from knn_points' squared
    distances): clamp((far - d2) / (far - near), 0, 1)."""
    lm = landmarks.double()
    d2 = torch.cat([torch.cdist(xyz[i:i + 65536].double(), lm).square().min(dim=1).values.float()
                    for i in range(0, len(xyz), 65536)]) if len(xyz) else torch.zeros(0)
    return torch.clamp((far - d2) / (far - near), 0.0, 1.0)


def _network(dims: list[int], inputs: list[InputSpec], routes: list[Route], blend: str, tanh: bool,
             feature_dim: int, exp_dim: int) -> MLPConfig:
    depth = len(dims) - 1
    skip = (len(dims)) // 2
    return MLPConfig(feature_dim=feature_dim, code_dim=exp_dim, hidden=dims[1] if depth > 1 else 1, depth=depth,
                     activation="leaky_relu", slope=0.01, skips=[skip] if skip < depth else [], inputs=inputs,
                     condition_dim=6, output_activation="tanh" if tanh else "none", routes=routes,
                     out_width=dims[-1], blend=blend)


def _load_mlp(cfg: MLPConfig, state: dict, name: str) -> ConditionedMLP:
    net = ConditionedMLP(cfg)
    with torch.no_grad():
        for i, layer in enumerate(net.layers):
            layer.weight.copy_(state[f"{name}.conv{i}.weight"][:, :, 0])  # type: ignore[operator]
            layer.bias.copy_(state[f"{name}.conv{i}.bias"])  # type: ignore[operator]
    return net.eval()


def expression_space_from(seq: ExpressionSequence, exp_dim: int, source: str | Path) -> ExpressionSpace:
    """The PCA of a sequence's expression coefficients (its frame vectors' first `exp_dim` columns) as the
    avatar's expression space: the condition part stays at zero (GHA's frontal head pose)."""
    if seq.dim != exp_dim + 6:
        raise AvatarFileError(source, f"has frame vectors of {seq.dim} values; the checkpoint takes {exp_dim} "
                              "expression coefficients and a 6-D pose")
    if len(seq) < 2:
        raise AvatarFileError(source, "has fewer than 2 frames: no PCA")
    pca = ExpressionSpace.from_codes(seq.codes[:, :exp_dim])
    pad = np.zeros((pca.n_components, 6), np.float32)
    return ExpressionSpace(np.concatenate([pca.mean, np.zeros(6, np.float32)]),
                           np.concatenate([pca.basis, pad], 1), pca.std, {})


def import_gha(folder: str | Path, config: str | Path | None = None, legacy_rotation: bool = False,
               sequence: ExpressionSequence | None = None, sequence_name: str = "") -> Avatar:
    """The avatar of a GHA checkpoint folder (`gaussianhead_latest`, optional `supres_latest`); its expression
    space is the PCA of `sequence`'s coefficients when one is given, else the raw coefficients with unit std."""
    folder = Path(folder)
    head_path = folder / HEAD if is_folder(folder) else folder
    state = load_state_dict(head_path, "a GHA gaussianhead checkpoint")
    xyz = _tensor(state, "xyz", (None, 3), head_path)
    n = xyz.shape[0]
    if not 0 < n <= MAX_GAUSSIANS:
        raise AvatarFileError(head_path, f"has {n} Gaussians (1..{MAX_GAUSSIANS} supported)")
    feature = _tensor(state, "feature", (n, None), head_path)
    landmarks = _tensor(state, "landmarks_3d_neutral", (None, 3), head_path)
    scales = _tensor(state, "scales", (n, 3), head_path)
    rotation = _tensor(state, "rotation", (n, 4), head_path)
    opacity = _tensor(state, "opacity", (n, 1), head_path)
    if not 0 < len(landmarks) <= MAX_LANDMARKS:
        raise AvatarFileError(head_path, f"has {len(landmarks)} neutral landmarks (1..{MAX_LANDMARKS}; GHA's have 68)")
    for key, limit in _RANGES.items():  # what the .npga reader and the renderer accept
        bounded_floats(state[key].numpy(), head_path, key, limit)
    if bool((rotation.square().sum(1) < 1e-16).any()):
        raise AvatarFileError(head_path, "rotation has zero-length quaternions")
    dims = {name: _mlp_dims(state, f"{name}_mlp", head_path) for name in NETWORKS}
    f_dim = feature.shape[1]
    exp_dim = dims["exp_color"][0] - f_dim
    pose_enc = dims["pose_color"][0] - f_dim
    if exp_dim < 1 or pose_enc % 6 or (pose_enc // 6) % 2 != 1:
        raise AvatarFileError(head_path, f"exp_color takes {dims['exp_color'][0]} and pose_color "
                              f"{dims['pose_color'][0]} inputs, which do not fit {f_dim} features and a 6-D pose")
    freqs = (pose_enc // 6 - 1) // 2
    expected = {"exp_color": f_dim + exp_dim, "exp_attributes": f_dim + exp_dim, "pose_attributes": f_dim + pose_enc,
                "exp_deform": 3 * (1 + 2 * freqs) + exp_dim, "pose_deform": 3 * (1 + 2 * freqs) + pose_enc}
    outs = {"exp_color": None, "pose_color": dims["exp_color"][-1], "exp_attributes": 8, "pose_attributes": 8,
            "exp_deform": 3, "pose_deform": 3}
    for name, want in expected.items():
        if dims[name][0] != want or (outs[name] is not None and dims[name][-1] != outs[name]):
            raise AvatarFileError(head_path, f"{name}_mlp has dims {dims[name]}, inconsistent with the others")
    settings, source = dict(PUBLISHED), CONFIG_SOURCE
    if config is not None:
        given = read_config(Path(config))
        if "pos_freq" in given and int(given["pos_freq"]) != freqs:
            raise AvatarFileError(Path(config), f"pos_freq {int(given['pos_freq'])} does not fit the checkpoint's "
                                  f"networks (they take {freqs} frequencies)")
        settings.update({k: v for k, v in given.items() if k in PUBLISHED})
        source = f"the config {Path(config).name}"
    near, far = settings["dist_threshold_near"], settings["dist_threshold_far"]
    if not far > near:
        raise AvatarFileError(Path(config or head_path), f"dist_threshold_far {far} must exceed the near one {near}")
    w_exp = blend_weights(xyz, landmarks, near, far)
    group = torch.where(w_exp >= 1.0, 0, torch.where(w_exp <= 0.0, 2, 1))
    order = torch.argsort(group, stable=True).numpy()
    channels = dims["exp_color"][-1]
    cloud = GaussianCloud(
        means=xyz.numpy()[order], quats=rotation.numpy()[order], log_scales=scales.numpy()[order],
        opacity_logits=opacity[:, 0].numpy()[order],
        sh=np.full((n, 1, 3), -0.5 / SH_C0, np.float32),  # colour 0; the networks add the first 3 channels
        features=torch.tanh(feature).numpy()[order], latent=np.zeros((n, channels), np.float32),
        part_ids=group.numpy().astype(np.int16)[order], part_names=list(PART_NAMES),
        blend_weights=torch.stack([w_exp, 1.0 - w_exp], 1).numpy()[order], blend_names=["expression", "pose"])
    pos = InputSpec("position", "gha", freqs)
    cond = InputSpec("condition", "gha", freqs)
    feat, code = InputSpec("features"), InputSpec("code")
    colour = [Route("latent", 0, channels), Route("sh", 0, 3, 0, 1.0 / SH_C0)]
    a_s, d_s = settings["attributes_scale"], settings["deform_scale"]
    attrs = [Route("scale", 0, 3, 0, a_s), Route("rotation", 3, 4, 0, a_s), Route("opacity", 7, 1, 0, a_s)]
    plan = {
        "exp_color": ([feat, code], colour, "expression", False),
        "pose_color": ([feat, cond], colour, "pose", False),
        "exp_attributes": ([feat, code], attrs, "expression", False),
        "pose_attributes": ([feat, cond], attrs, "pose", False),
        "exp_deform": ([pos, code], [Route("position", 0, 3, 0, d_s)], "expression", True),
        "pose_deform": ([pos, cond], [Route("position", 0, 3, 0, d_s)], "pose", True),
    }
    try:  # what a network description cannot hold (hidden width 0, fewer than 3 colour channels, ...)
        nets = {name: _load_mlp(_network(dims[name], *plan[name], f_dim, exp_dim), state, f"{name}_mlp")
                for name in NETWORKS}
    except (ValueError, RuntimeError) as e:
        raise AvatarFileError(head_path, f"networks that an .npga cannot describe ({e})") from None
    note = (f"clamp((far - d2) / (far - near), 0, 1), d2 the squared distance to the nearest of the checkpoint's "
            f"{len(landmarks)} landmarks_3d_neutral (GHA generate(), knn_points), near {near}, far {far}")
    dynamics = Dynamics(networks=nets, rules={"rotation": "add_raw_legacy" if legacy_rotation else "add_raw"},
                        condition=dict(CONDITION), blend_notes={"expression": note, "pose": "1 - expression"})
    cnn = _import_supres(folder / SUPRES, channels) if folder.is_dir() and (folder / SUPRES).exists() else None
    d = exp_dim + 6
    if sequence is not None:
        space = expression_space_from(sequence, exp_dim, sequence_name or "the sequence")
        space_note = f"PCA of the expression coefficients of {len(sequence)} frames of {sequence_name or 'a sequence'}"
    else:
        space = ExpressionSpace(np.zeros(d, np.float32), np.eye(exp_dim, d, dtype=np.float32),
                                np.ones(exp_dim, np.float32), {})
        space_note = "the raw expression coefficients, unit std (GHA has no PCA; import with --sequence for one)"
    counts = np.bincount(group.numpy(), minlength=3)
    provenance = {
        "source": "Gaussian-Head-Avatar checkpoint", "path": str(folder), "imported_by": "npga-view import gha",
        "settings": settings, "settings_from": source,
        "rotation_normalisation": "legacy (before 2024-07-12, across Gaussians)" if legacy_rotation else
        "per Gaussian (GHA since 2024-07-12)",
        "groups": {"near": int(counts[0]), "blended": int(counts[1]), "far": int(counts[2])},
        "super_resolution": SUPRES if cnn is not None else "none (the first three colour channels are the image)",
        "expression_space": space_note + "; the pose condition comes from sequences",
    }
    return Avatar(cloud, dynamics, cnn, space, provenance=provenance, source=str(folder))


def _import_supres(path: Path, channels: int) -> ScreenCNN:
    """GHA's `Upsampler` (lib/network/Upsampler.py) as a CNN description with its weights."""
    state = load_state_dict(path, "a GHA super-resolution checkpoint")
    prefixes = ["upsampler.inc.double_conv", "upsampler.up1.conv.double_conv", "upsampler.up2.conv.double_conv"]
    ops: list[dict] = []
    weights: list[tuple[torch.Tensor, torch.Tensor | None]] = []
    for stage, prefix in enumerate(prefixes):
        if stage:
            ops.append({"op": "upsample", "factor": 2, "mode": "bilinear", "align_corners": True})
        for idx in (0, 3):  # nn.Sequential(conv, InstanceNorm2d, ReLU, conv, InstanceNorm2d, ReLU)
            w = _tensor(state, f"{prefix}.{idx}.weight", (None, None, 3, 3), path)
            ops += [{"op": "conv", "in": int(w.shape[1]), "out": int(w.shape[0]), "kernel": 3, "bias": False},
                    {"op": "instance_norm", "eps": 1e-5}, {"op": "act", "name": "relu"}]
            weights.append((w, None))
    w = _tensor(state, "upsampler.outc.conv.weight", (3, None, 1, 1), path)
    b = _tensor(state, "upsampler.outc.conv.bias", (3,), path)
    ops += [{"op": "conv", "in": int(w.shape[1]), "out": 3, "kernel": 1, "bias": True},
            {"op": "act", "name": "sigmoid"}]
    weights.append((w, b))
    try:
        cnn = ScreenCNN(CNNConfig(residual=False, ops=ops, input="latent", latent_background=1.0))
        cnn.config.validate(channels)
    except ValueError as e:
        raise AvatarFileError(path, f"does not fit the Gaussians' {channels} colour channels ({e})") from None
    with torch.no_grad():
        for conv, (weight, bias) in zip(cnn.convs, weights, strict=True):
            conv.weight.copy_(weight)  # type: ignore[operator]
            if bias is not None:
                conv.bias.copy_(bias)  # type: ignore[operator]
    return cnn.eval()


# --------------------------------------------------------------------------------------------------------------
# sequences: GHA's per-frame params folders

def _params_files(root: Path) -> list[Path]:
    base = root / "params" if (root / "params").is_dir() else root
    frames = sorted((p for p in base.iterdir() if p.is_dir() and (p / "params.npz").exists()),
                    key=lambda p: (len(p.name), p.name))
    return [p / "params.npz" for p in frames]


def is_gha_params(path: str | Path) -> bool:
    """True when `path` is a GHA dataset folder (with `params/`) or its `params/` folder of frame folders."""
    p = Path(path)
    if not p.is_dir():
        return False
    base = p / "params" if (p / "params").is_dir() else p
    return any((f / "params.npz").exists() for f in list(base.iterdir())[:64] if f.is_dir())


def read_gha_params(root: str | Path, fps: float = DEFAULT_FPS) -> ExpressionSequence:
    """GHA's `params/NNNN/params.npz` frames as GHA's Dataset reads them (lib/dataset/Dataset.py: `pose[0]`,
    `scale`, `exp_coeff[0]`): frame vectors [exp_coeff, pose] and the head pose x' = s R x + t."""
    root = Path(root)
    files = _params_files(root)
    if not files:
        raise AvatarFileError(root, "has no params/NNNN/params.npz frames")
    codes, poses, scales = [], [], []
    for f in files:
        z = read_npz(f, 1 << 20, keys=("exp_coeff", "pose", "scale"))
        for key in ("exp_coeff", "pose", "scale"):
            if key not in z:
                raise AvatarFileError(f, f"has no {key!r} (not a GHA params file)")
        exp, pose, scale = (np.asarray(z[k], np.float64) for k in ("exp_coeff", "pose", "scale"))
        if exp.ndim != 2 or pose.shape != (1, 6) or scale.size != 1 or len(exp) != 1:
            raise AvatarFileError(f, f"exp_coeff {exp.shape}, pose {pose.shape}, scale {scale.shape}: expected "
                                  "(1, E), (1, 6) and one scale")
        codes.append(np.concatenate([exp[0], pose[0]]))
        poses.append(pose[0])
        scales.append(float(scale.reshape(-1)[0]))
    widths = {len(c) for c in codes}
    if len(widths) > 1:
        raise AvatarFileError(root, f"frames have expression codes of different widths {sorted(widths)}")
    c = np.stack(codes)
    if not np.isfinite(c).all() or not np.isfinite(scales).all() or np.abs(c).max() > 1e4:
        raise AvatarFileError(root, "has NaN, Inf or implausibly large values in exp_coeff or pose")
    p = np.stack(poses)
    pose = similarity_pose(p[:, :3], p[:, 3:], np.asarray(scales), len(p), root)  # checked, naming the folder
    return ExpressionSequence(c.astype(np.float32), fps, root.name, pose=pose,
                              frame_names=[f.parent.name for f in files],
                              pose_source="GHA params.npz: x' = s R(axis-angle) x + t, as GHA's generate()")
