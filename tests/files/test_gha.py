"""Gaussian-Head-Avatar checkpoints: the imported avatar poses exactly as GHA's own `generate()`.

Two references:
- `_generate_as_read` below, written from our reading of GHA's code (YuelangX/Gaussian-Head-Avatar at d006861,
  2024-07-12): lib/module/GaussianHeadModule.py lines 58-141 (`generate`), lib/network/MLP.py lines 11-39 (skip
  at int(len(dims) / 2), leaky ReLU, last_op), lib/network/PositionalEmbedding.py lines 37-52 (x, sin(2^k x),
  cos(2^k x)), lib/network/Upsampler.py lines 6-85. It always runs.
- GHA's own code, when a checkout of it is named by $NPGA_GHA_SOURCE (its licence allows no copying, so none of
  it is in this project): its `GaussianHeadModule.generate` and `Upsampler` run on the same weights. Its CUDA-only
  or compiled helpers are replaced by the documented operations (pytorch3d's `knn_points` returns squared
  distances, `so3_exponential_map` is Rodrigues' formula, `quaternion_to_matrix` works on non-unit quaternions).
"""

from __future__ import annotations

import importlib
import os
import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch

from npga_core.errors import AvatarFileError
from npga_core.files.checkpoint import read_avatar, read_header, save_avatar
from npga_core.files.gha import import_gha, is_gha_folder, read_gha_params
from npga_core.files.gha_synthetic import gha_state_dicts, write_gha_folder, write_gha_params
from npga_core.files.loading import load_avatar, load_sequence
from npga_core.model.gaussians import SH_C0
from npga_core.model.rotations import matrix_from_rotvec, similarity
from npga_core.posing.fastpose import FastPoser, posed_buffers

SMALL = {"feature_dim": 12, "exp_dim": 6, "hidden": 32, "channels": 8, "freqs": 2, "capacity": 4}
SETTINGS = {"dist_threshold_near": 0.1, "dist_threshold_far": 0.25, "deform_scale": 0.3, "attributes_scale": 0.2}


# --- GHA's generate() as we read it --------------------------------------------------------------------------
def _embed(x: torch.Tensor, freqs: int) -> torch.Tensor:
    """PositionalEmbedding.get_embedder: include_input, log sampling 2^0 .. 2^(freqs-1), sin then cos."""
    return torch.cat([x] + [f(x * 2.0**k) for k in range(freqs) for f in (torch.sin, torch.cos)], -1)


def _mlp(state: dict, name: str, x: torch.Tensor, last_tanh: bool) -> torch.Tensor:
    """MLP.forward on rows x (N, dims[0]): Conv1d(k=1) = linear; skip layer int(len(dims)/2) takes [y, input]."""
    n_layers = len([k for k in state if k.startswith(f"{name}.conv") and k.endswith(".weight")])
    skip = (n_layers + 1) // 2
    y = x
    for i in range(n_layers):
        inp = torch.cat([y, x], 1) if i == skip else y
        y = inp @ state[f"{name}.conv{i}.weight"][:, :, 0].T + state[f"{name}.conv{i}.bias"]
        if i != n_layers - 1:
            y = torch.nn.functional.leaky_relu(y)
    return torch.tanh(y) if last_tanh else y


def _generate_as_read(state: dict, s: dict, exp: torch.Tensor, pose: torch.Tensor, scale: float, freqs: int,
                      legacy: bool = False) -> dict:
    xyz, feature = state["xyz"], torch.tanh(state["feature"])
    d2 = torch.cdist(xyz.double(), state["landmarks_3d_neutral"].double()).square().min(1).values.float()[:, None]
    w_exp = torch.clamp((s["dist_threshold_far"] - d2) / (s["dist_threshold_far"] - s["dist_threshold_near"]), 0, 1)
    w_pose = 1 - w_exp
    n = len(xyz)
    e_in = torch.cat([feature, exp.expand(n, -1)], 1)
    p_in = torch.cat([feature, _embed(pose, freqs).expand(n, -1)], 1)
    color = _mlp(state, "exp_color_mlp", e_in, False) * w_exp + _mlp(state, "pose_color_mlp", p_in, False) * w_pose
    attrs = (_mlp(state, "exp_attributes_mlp", e_in, False) * w_exp
             + _mlp(state, "pose_attributes_mlp", p_in, False) * w_pose)
    pe = _embed(xyz, freqs)
    deform = (_mlp(state, "exp_deform_mlp", torch.cat([pe, exp.expand(n, -1)], 1), True) * w_exp
              + _mlp(state, "pose_deform_mlp", torch.cat([pe, _embed(pose, freqs).expand(n, -1)], 1), True) * w_pose)
    xyz = xyz + deform * s["deform_scale"]
    scales = torch.exp(state["scales"] + attrs[:, 0:3] * s["attributes_scale"])
    rot = state["rotation"] + attrs[:, 3:7] * s["attributes_scale"]
    rot = rot / rot.norm(dim=0 if legacy else 1, keepdim=True).clamp_min(1e-12)
    opacity = torch.sigmoid(state["opacity"] + attrs[:, 7:8] * s["attributes_scale"])
    r = torch.from_numpy(matrix_from_rotvec(pose[:3].double().numpy())).float()
    xyz = (xyz * scale) @ r.T + pose[3:]
    rot = rot / rot.norm(dim=1, keepdim=True)
    rm = torch.from_numpy(np.asarray([_quat_matrix(q) for q in rot.double().numpy()])).float()
    rot = torch.from_numpy(np.asarray([_matrix_quat(m) for m in (r @ rm).double().numpy()])).float()
    return {"xyz": xyz, "color": color, "scales": scales * scale, "rotation": rot, "opacity": opacity}


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _matrix_quat(m: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(m).as_quat()
    return np.array([w, x, y, z])


# --- helpers ---------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_gha(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gha") / "ckpt"
    write_gha_folder(folder, n=900, seed=3, **SMALL)
    return folder


def _original_rows(avatar, xyz: np.ndarray) -> np.ndarray:
    """For each of the avatar's Gaussians, its row in GHA's order (the importer sorts near/blended/far)."""
    index = {row.tobytes(): i for i, row in enumerate(np.asarray(xyz, np.float32))}
    return np.array([index[row.tobytes()] for row in np.asarray(avatar.cloud.means, np.float32)])


def _ours(avatar, exp: torch.Tensor, pose: torch.Tensor, scale: float, fast: bool):
    z = np.concatenate([exp.numpy(), pose.numpy()]).astype(np.float32)
    head = similarity(matrix_from_rotvec(pose[:3].double().numpy()), pose[3:].double().numpy(), scale)
    if not fast:
        return avatar.pose(z, reference=True, head=head)
    from npga_core.model.gaussians import PosedGaussians
    from npga_core.model.rigid import transform_posed

    buf = posed_buffers(len(avatar), 1, avatar.cloud.latent_dim)
    FastPoser(avatar, chunk=128, threads=2).pose_into(z, buf)
    return transform_posed(PosedGaussians(**buf), head)


def _assert_same(ours, ref: dict, rows: np.ndarray, tol: float = 1e-5) -> None:
    ref = {k: v.detach().numpy()[rows] for k, v in ref.items()}
    np.testing.assert_allclose(ours.means, ref["xyz"], atol=tol, rtol=tol)
    np.testing.assert_allclose(ours.scales, ref["scales"], atol=tol, rtol=tol)
    np.testing.assert_allclose(ours.opacities, ref["opacity"][:, 0], atol=tol, rtol=tol)
    np.testing.assert_allclose(ours.latent, ref["color"], atol=tol, rtol=tol)  # all K colour channels
    np.testing.assert_allclose(ours.sh[:, 0] * SH_C0 + 0.5, ref["color"][:, :3], atol=tol, rtol=tol)
    q, r = ours.quats, ref["rotation"]
    sign = np.sign(np.sum(q * r, axis=1, keepdims=True))
    np.testing.assert_allclose(q * sign, r, atol=tol, rtol=tol)


def _frames(rng, exp_dim: int, count: int = 3):
    for _ in range(count):
        pose = torch.tensor(np.concatenate([rng.normal(0, 0.3, 3), rng.normal(0, 0.1, 3)]), dtype=torch.float32)
        yield torch.tensor(rng.normal(0, 1.0, exp_dim), dtype=torch.float32), pose, float(rng.uniform(0.8, 1.2))


# --- tests -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fast", [False, True])
def test_import_poses_as_generate_reads(small_gha, fast):
    state = torch.load(small_gha / "gaussianhead_latest", weights_only=True)
    avatar = import_gha(small_gha)
    groups = avatar.provenance["groups"]
    assert min(groups.values()) > 0, groups  # near, blended and far Gaussians all present
    rows = _original_rows(avatar, state["xyz"].numpy())
    for exp, pose, scale in _frames(np.random.default_rng(0), SMALL["exp_dim"]):
        ref = _generate_as_read(state, SETTINGS, exp, pose, scale, SMALL["freqs"])
        _assert_same(_ours(avatar, exp, pose, scale, fast), ref, rows)


@pytest.mark.parametrize("fast", [False, True])
def test_legacy_rotation_normalises_across_gaussians(small_gha, fast):
    state = torch.load(small_gha / "gaussianhead_latest", weights_only=True)
    avatar = import_gha(small_gha, legacy_rotation=True)
    rows = _original_rows(avatar, state["xyz"].numpy())
    exp, pose, scale = next(_frames(np.random.default_rng(1), SMALL["exp_dim"]))
    _assert_same(_ours(avatar, exp, pose, scale, fast), _generate_as_read(state, SETTINGS, exp, pose, scale,
                                                                          SMALL["freqs"], legacy=True), rows)
    today = import_gha(small_gha)
    assert not np.allclose(_ours(today, exp, pose, scale, False).quats, _ours(avatar, exp, pose, scale, False).quats,
                           atol=1e-3)


def test_config_settings_are_used_and_recorded(small_gha, tmp_path):
    cfg = tmp_path / "train.yaml"
    cfg.write_text("gaussianheadmodule:\n  pos_freq: 2\n  dist_threshold_near: 0.05\n  dist_threshold_far: 0.3\n"
                   "  deform_scale: 0.5\n  attributes_scale: 0.1\n")
    a = import_gha(small_gha, config=cfg)
    assert a.provenance["settings"]["deform_scale"] == 0.5 and "train.yaml" in a.provenance["settings_from"]
    state = torch.load(small_gha / "gaussianhead_latest", weights_only=True)
    s = {"dist_threshold_near": 0.05, "dist_threshold_far": 0.3, "deform_scale": 0.5, "attributes_scale": 0.1}
    exp, pose, scale = next(_frames(np.random.default_rng(2), SMALL["exp_dim"]))
    _assert_same(_ours(a, exp, pose, scale, False), _generate_as_read(state, s, exp, pose, scale, 2),
                 _original_rows(a, state["xyz"].numpy()))
    assert "published" in import_gha(small_gha).provenance["settings_from"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("gaussianheadmodule:\n  pos_freq: 4\n")
    with pytest.raises(AvatarFileError, match="pos_freq 4"):
        import_gha(small_gha, config=bad)


def _upsampler_as_read(sd: dict, x: torch.Tensor) -> torch.Tensor:
    """Upsampler.forward: DoubleConv (3x3 no bias, InstanceNorm2d, ReLU) x2, Up = bilinear x2 aligned corners +
    DoubleConv, 1x1 OutConv with bias, sigmoid."""
    f = torch.nn.functional

    def double(prefix, h):
        for i in (0, 3):
            h = f.relu(f.instance_norm(f.conv2d(h, sd[f"{prefix}.{i}.weight"], padding=1)))
        return h

    h = double("upsampler.inc.double_conv", x)
    for up in ("up1", "up2"):
        h = double(f"upsampler.{up}.conv.double_conv", f.interpolate(h, scale_factor=2, mode="bilinear",
                                                                     align_corners=True))
    return torch.sigmoid(f.conv2d(h, sd["upsampler.outc.conv.weight"], sd["upsampler.outc.conv.bias"]))


def test_super_resolution_network_as_read(small_gha):
    sd = torch.load(small_gha / "supres_latest", weights_only=True)
    cnn = import_gha(small_gha).cnn
    assert cnn is not None and cnn.config.upsample == 4 and cnn.config.band_halo() is None
    x = torch.rand(1, SMALL["channels"], 12, 10, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(cnn(x), _upsampler_as_read(sd, x), atol=1e-5, rtol=1e-5)
    out = cnn.refine(x[0].permute(1, 2, 0).numpy())
    assert out.shape == (48, 40, 3)


def test_saved_avatar_reopens_with_the_same_posed_output(small_gha, tmp_path):
    a = import_gha(small_gha)
    path = tmp_path / "gha.npga"
    save_avatar(a, path)
    header, _ = read_header(path)
    assert header["format_version"] == 2 and set(header["dynamics"]["networks"]) == {
        "exp_color", "pose_color", "exp_attributes", "pose_attributes", "exp_deform", "pose_deform"}
    b = read_avatar(path)
    z = np.random.default_rng(3).normal(0, 1, a.code_dim).astype(np.float32)
    p, q = a.pose(z), b.pose(z)
    for name in ("means", "quats", "scales", "opacities", "sh", "latent"):
        np.testing.assert_array_equal(getattr(p, name), getattr(q, name), err_msg=name)
    x = torch.rand(1, SMALL["channels"], 8, 8)
    with torch.no_grad():
        torch.testing.assert_close(a.cnn(x), b.cnn(x))
    assert b.cloud.blend_names == ["expression", "pose"] and b.dynamics.condition["dim"] == 6


def test_folder_opens_directly_and_params_as_a_sequence(small_gha, tmp_path):
    assert is_gha_folder(small_gha)
    a = load_avatar(small_gha)
    assert a.code_dim == SMALL["exp_dim"] + 6 and a.condition_dim == 6
    root = write_gha_params(tmp_path / "data", frames=4, exp_dim=SMALL["exp_dim"])
    seq = load_sequence(root)
    assert seq.codes.shape == (4, SMALL["exp_dim"] + 6)
    # as GHA's Dataset reads a frame (lib/dataset/Dataset.py 388-392): pose[0], scale, exp_coeff[0]
    raw = np.load(root / "params" / "0002" / "params.npz")
    np.testing.assert_allclose(seq.codes[2], np.concatenate([raw["exp_coeff"][0], raw["pose"][0]]), rtol=1e-6)
    m = seq.pose[2]
    x = np.array([0.1, -0.2, 0.3])
    want = raw["scale"][0] * matrix_from_rotvec(raw["pose"][0, :3].astype(np.float64)) @ x + raw["pose"][0, 3:]
    np.testing.assert_allclose(m[:3, :3] @ x + m[:3, 3], want, rtol=1e-5, atol=1e-6)
    assert read_gha_params(root / "params").codes.shape == seq.codes.shape
    # an expression code alone poses with the neutral condition (zero pose)
    z = seq.codes[1, : SMALL["exp_dim"]]
    np.testing.assert_array_equal(a.pose(z).means, a.pose(np.concatenate([z, np.zeros(6, np.float32)])).means)


class _Payload:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_hostile_checkpoints_are_refused_in_one_line(small_gha, tmp_path):
    marker = tmp_path / "executed"
    head, _ = gha_state_dicts(200, 0, **SMALL)
    cases = {}
    evil = tmp_path / "evil"
    evil.mkdir()
    torch.save({**head, "x": _Payload(marker)}, evil / "gaussianhead_latest")
    cases["evil"] = ("more than tensors", evil)
    raw = tmp_path / "rawpickle"
    raw.mkdir()
    (raw / "gaussianhead_latest").write_bytes(pickle.dumps(_Payload(marker)))
    cases["raw"] = ("", raw)
    for name, change, match in (("missing", lambda d: d.pop("opacity"), "no 'opacity'"),
                                ("misshaped", lambda d: d.__setitem__("scales", torch.zeros(7, 3)), "scales"),
                                ("nan", lambda d: d["xyz"].__setitem__((0, 0), float("nan")), "NaN"),
                                ("mlp", lambda d: d.pop("exp_color_mlp.conv1.weight"), "exp_color")):
        d = {k: v.clone() for k, v in head.items()}
        change(d)
        folder = tmp_path / name
        folder.mkdir()
        torch.save(d, folder / "gaussianhead_latest")
        cases[name] = (match, folder)
    (tmp_path / "trunc").mkdir()
    (tmp_path / "trunc" / "gaussianhead_latest").write_bytes((small_gha / "gaussianhead_latest").read_bytes()[:500])
    cases["trunc"] = ("", tmp_path / "trunc")
    for name, (match, folder) in cases.items():
        with pytest.raises(AvatarFileError) as e:
            load_avatar(folder)
        msg = str(e.value)
        assert "\n" not in msg and "gaussianhead_latest" in msg and match in msg, (name, msg)
    assert not marker.exists()


def test_cli_import_and_bad_input(small_gha, tmp_path):
    import subprocess

    out = tmp_path / "a.npga"
    r = subprocess.run([sys.executable, "-m", "npga_view", "import", "gha", str(small_gha), "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert read_avatar(out).provenance["source"] == "Gaussian-Head-Avatar checkpoint"
    (tmp_path / "empty").mkdir()
    r = subprocess.run([sys.executable, "-m", "npga_view", "import", "gha", str(tmp_path / "empty"), "--out",
                        str(tmp_path / "b.npga")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "b.npga").exists()


# --- GHA's own code ----------------------------------------------------------------------------------------------
GHA_SOURCE = os.environ.get("NPGA_GHA_SOURCE", "")


def _gha_modules(monkeypatch) -> types.ModuleType:
    root = Path(GHA_SOURCE)
    if not (root / "lib" / "module" / "GaussianHeadModule.py").is_file():
        pytest.skip("GHA's source is not here: set $NPGA_GHA_SOURCE to a checkout of YuelangX/Gaussian-Head-Avatar")
    from scipy.spatial.transform import Rotation

    def knn_points(p1, p2, K=1):  # noqa: N803 - pytorch3d's signature; returns squared distances
        d2 = torch.cdist(p1.double(), p2.double()).square()
        dists, idx = d2.topk(K, dim=-1, largest=False)
        return dists.float(), idx, None

    def so3_exponential_map(v):
        return torch.from_numpy(Rotation.from_rotvec(v.double().numpy()).as_matrix()).float()

    def quaternion_to_matrix(q):  # pytorch3d: two_s = 2 / |q|^2, valid for non-unit quaternions
        flat = q.reshape(-1, 4).double().numpy()
        return torch.from_numpy(np.stack([_quat_matrix(x) for x in flat])).float().reshape(*q.shape[:-1], 3, 3)

    def matrix_to_quaternion(m):
        flat = m.reshape(-1, 3, 3).double().numpy()
        return torch.from_numpy(np.stack([_matrix_quat(x) for x in flat])).float().reshape(*m.shape[:-2], 4)

    def rearrange(t, pattern, **kw):
        if pattern == "b n x y -> (b n) x y":
            return t.reshape(-1, *t.shape[2:])
        return t.reshape(kw["b"], -1, *t.shape[1:])

    fakes = {"pytorch3d": {}, "pytorch3d.ops": {}, "pytorch3d.ops.knn": {"knn_points": knn_points, "knn_gather": None},
             "pytorch3d.transforms": {"so3_exponential_map": so3_exponential_map},
             "pytorch3d.transforms.rotation_conversions": {"quaternion_to_matrix": quaternion_to_matrix,
                                                           "matrix_to_quaternion": matrix_to_quaternion},
             "simple_knn": {}, "simple_knn._C": {"distCUDA2": lambda x: torch.ones(len(x))},
             "einops": {"rearrange": rearrange}, "tqdm": {}}
    for name, attrs in fakes.items():
        if name in ("einops", "tqdm") and importlib.util.find_spec(name) is not None:
            continue
        mod = types.ModuleType(name)
        for k, v in attrs.items():
            setattr(mod, k, v)
        monkeypatch.setitem(sys.modules, name, mod)
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setattr(torch.Tensor, "cuda", lambda self, *a, **k: self)
    for name in [m for m in sys.modules if m == "lib" or m.startswith("lib.")]:
        monkeypatch.delitem(sys.modules, name)
    return importlib.import_module("lib.module.GaussianHeadModule")


def test_against_ghas_own_generate(small_gha, monkeypatch):
    module = _gha_modules(monkeypatch)
    state = torch.load(small_gha / "gaussianhead_latest", weights_only=True)
    cfg = types.SimpleNamespace(num_add_mouth_points=0, pos_freq=SMALL["freqs"], exp_coeffs_dim=SMALL["exp_dim"],
                                **SETTINGS)
    for name in ("exp_color", "pose_color", "exp_attributes", "pose_attributes", "exp_deform", "pose_deform"):
        n_layers = len([k for k in state if k.startswith(f"{name}_mlp.conv") and k.endswith(".weight")])
        dims = [int(state[f"{name}_mlp.conv0.weight"].shape[1])]
        dims += [int(state[f"{name}_mlp.conv{i}.weight"].shape[0]) for i in range(n_layers)]
        setattr(cfg, f"{name}_mlp", dims)
    gha = module.GaussianHeadModule(cfg, state["xyz"], state["feature"], state["landmarks_3d_neutral"])
    gha.load_state_dict(state)
    # GHA before 2024-07-12 (0c799aa) normalised the rotations with F.normalize(rotation), i.e. over dim 1 of
    # (B, N, 4): across the Gaussians; d006861 added dim=2. Whichever this checkout is, --legacy-rotation matches it.
    legacy = "normalize(rotation, dim=2)" not in Path(module.__file__).read_text()
    avatar = import_gha(small_gha, legacy_rotation=legacy)
    rows = _original_rows(avatar, state["xyz"].numpy())
    for exp, pose, scale in _frames(np.random.default_rng(4), SMALL["exp_dim"]):
        with torch.no_grad():
            out = gha.generate({"exp_coeff": exp[None], "pose": pose[None], "scale": torch.tensor([[scale]])})
        ref = {k: out[k][0] for k in ("xyz", "color", "scales", "rotation", "opacity")}
        _assert_same(_ours(avatar, exp, pose, scale, True), ref, rows)


def test_against_ghas_own_upsampler(small_gha, monkeypatch):
    _gha_modules(monkeypatch)
    up = importlib.import_module("lib.network.Upsampler")
    sd = torch.load(small_gha / "supres_latest", weights_only=True)
    net = up.Upsampler(SMALL["channels"], 3, SMALL["capacity"])
    net.load_state_dict({k[len("upsampler."):]: v for k, v in sd.items()})
    x = torch.rand(1, SMALL["channels"], 12, 10, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        torch.testing.assert_close(import_gha(small_gha).cnn(x), net.eval()(x), atol=1e-5, rtol=1e-5)


def test_export_writes_the_posed_gaussians_with_their_colour_channels(small_gha, tmp_path):
    from npga_view.cli.main import main

    data = write_gha_params(tmp_path / "data", frames=4, exp_dim=SMALL["exp_dim"])
    out = tmp_path / "posed.ply"
    assert main(["export", str(small_gha), "--sequence", str(data), "--frame", "2", "--head-pose", "absolute",
                 "--out", str(out)]) == 0
    raw = out.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    names = [ln.split()[-1] for ln in raw[:end].decode().splitlines() if ln.startswith("property")]
    table = np.frombuffer(raw[end:], "<f4").reshape(-1, len(names))
    col = {n: table[:, i] for i, n in enumerate(names)}
    state = torch.load(small_gha / "gaussianhead_latest", weights_only=True)
    frame = np.load(data / "params" / "0002" / "params.npz")
    exp, pose = torch.from_numpy(frame["exp_coeff"][0]), torch.from_numpy(frame["pose"][0])
    ref = _generate_as_read(state, SETTINGS, exp, pose, float(frame["scale"][0]), SMALL["freqs"])
    avatar = import_gha(small_gha)
    rows = _original_rows(avatar, state["xyz"].numpy())
    ref = {k: v.numpy()[rows] for k, v in ref.items()}
    np.testing.assert_allclose(np.stack([col["x"], col["y"], col["z"]], 1), ref["xyz"], atol=1e-5, rtol=1e-5)
    np.testing.assert_allclose(np.exp(np.stack([col[f"scale_{i}"] for i in range(3)], 1)), ref["scales"], rtol=1e-4)
    np.testing.assert_allclose(1 / (1 + np.exp(-col["opacity"])), ref["opacity"][:, 0], atol=1e-5)
    k = SMALL["channels"]
    np.testing.assert_allclose(np.stack([col[f"latent_{i}"] for i in range(k)], 1), ref["color"], atol=1e-5)
    dc = np.stack([col[f"f_dc_{i}"] for i in range(3)], 1)
    np.testing.assert_allclose(dc * SH_C0 + 0.5, ref["color"][:, :3], atol=1e-5)
    q = np.stack([col[f"rot_{i}"] for i in range(4)], 1)
    sign = np.sign(np.sum(q * ref["rotation"], axis=1, keepdims=True))
    np.testing.assert_allclose(q * sign, ref["rotation"], atol=1e-5)


def test_expression_space_from_a_sequence(small_gha, tmp_path):
    root = write_gha_params(tmp_path / "data", frames=12, exp_dim=SMALL["exp_dim"])
    seq = load_sequence(root)
    a = import_gha(small_gha, sequence=seq, sequence_name="data")
    ex = a.expression
    assert ex.dim == SMALL["exp_dim"] + 6 and 1 <= ex.n_components <= SMALL["exp_dim"]
    np.testing.assert_allclose(ex.mean[: SMALL["exp_dim"]], seq.codes[:, : SMALL["exp_dim"]].mean(0), atol=1e-6)
    assert np.all(ex.basis[:, SMALL["exp_dim"]:] == 0) and np.all(ex.mean[SMALL["exp_dim"]:] == 0)
    # the first direction carries the largest variance of the coefficients
    proj = (seq.codes[:, : SMALL["exp_dim"]] - ex.mean[: SMALL["exp_dim"]]) @ ex.basis[0, : SMALL["exp_dim"]]
    np.testing.assert_allclose(proj.std(ddof=1), ex.std[0], rtol=1e-4)
    assert "PCA" in a.provenance["expression_space"]


def test_edited_gha_avatar_saves_and_reopens_with_the_same_posed_output(small_gha, tmp_path):
    from npga_core.editing.edits import DeleteSelected, EditSession

    a = import_gha(small_gha)
    s = EditSession(a)
    rng = np.random.default_rng(7)
    s.select(rng.random(len(a)) < 0.25)  # from all three groups: near, blended and far
    s.run(DeleteSelected())
    assert a.cloud.blend_weights.shape == (len(a), 2)
    z = np.random.default_rng(8).normal(0, 1, a.code_dim).astype(np.float32)
    buf = posed_buffers(len(a), 1, a.cloud.latent_dim)
    FastPoser(a, chunk=64, threads=2).pose_into(z, buf)  # the blended networks' row ranges after the deletion
    ref = a.pose(z, reference=True)
    np.testing.assert_allclose(buf["means"], ref.means, atol=1e-5)
    path = tmp_path / "edited.npga"
    save_avatar(a, path)
    b = read_avatar(path)
    np.testing.assert_array_equal(b.pose(z).means, a.pose(z).means)
    np.testing.assert_array_equal(b.pose(z).latent, a.pose(z).latent)


def test_subsets_run_each_network_on_its_rows_only_and_equal_the_full_pass(small_gha):
    a = import_gha(small_gha)
    poser = FastPoser(a, chunk=64, threads=2)
    assert 0.0 < poser.reach < 1.0  # the blended networks skip the rows they do not reach
    index = np.sort(np.random.default_rng(9).choice(len(a), 300, replace=False))
    rows = poser.subset(index)
    assert rows.spans and all(b - a_ < len(index) for a_, b in rows.spans.values())
    z = np.random.default_rng(10).normal(0, 1, a.code_dim).astype(np.float32)
    torch.testing.assert_close(poser.offsets(z, rows=rows), poser.offsets(z)[torch.from_numpy(index)], rtol=1e-4,
                               atol=1e-6)


def test_the_window_cnn_stops_between_operations_when_cancelled(small_gha):
    from npga_core.model.cnn import run_cnn_steps

    cnn = import_gha(small_gha).cnn
    image = np.random.default_rng(0).random((10, 12, SMALL["channels"]), dtype=np.float32)
    np.testing.assert_allclose(run_cnn_steps(cnn, image, lambda: False), cnn.refine(image), atol=1e-6)
    calls = []

    def cancel_after_three() -> bool:
        calls.append(1)
        return len(calls) > 3

    assert run_cnn_steps(cnn, image, cancel_after_three) is None and len(calls) == 4
