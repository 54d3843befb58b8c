"""docs/FORMAT.md against the code: its example writes a valid file, its tensor table and numpy reference match."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from npga_core.files.checkpoint import ALIGN, MAGIC, expected_tensors, read_avatar, read_header, save_avatar
from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import ConditionedMLP, Dynamics, MLPConfig
from npga_core.model.synthetic import make_synthetic_avatar

DOC = Path(__file__).resolve().parents[2] / "docs" / "FORMAT.md"
EXAMPLE_HEADING = "## 14. Example: writing a minimal file"
REFERENCE_HEADING = "### Reference implementation (numpy)"
TENSOR_HEADING = "## 3. Tensors"


def _doc() -> str:
    return DOC.read_text(encoding="utf-8")


def _python_block_after(heading: str) -> str:
    """The first ```python block after a heading line of the document."""
    text = _doc()
    start = text.find("\n" + heading + "\n")
    assert start >= 0, f"heading {heading!r} not found in {DOC}"
    m = re.search(r"^```python\n(.*?)^```$", text[start:], re.S | re.M)
    assert m, f"no python block after {heading!r}"
    return m.group(1)


def _section(heading: str) -> str:
    """Text from a '## ' heading to the next one."""
    text = _doc()
    start = text.find("\n" + heading + "\n")
    assert start >= 0, f"heading {heading!r} not found"
    end = text.find("\n## ", start + len(heading) + 2)
    return text[start : end if end >= 0 else len(text)]


def _generic(name: str) -> str:
    """A concrete tensor name in the document's generic form, e.g. dynamics.{F,G}.layers.{i}.weight."""
    name = re.sub(r"^dynamics\.[FG]\.", "dynamics.{F,G}.", name)
    return re.sub(r"\.layers\.\d+\.", ".layers.{i}.", name)


# --------------------------------------------------------------------------------------------------
# the example writer


def test_example_writes_a_valid_file(tmp_path):
    code = _python_block_after(EXAMPLE_HEADING)
    assert "npga_core" not in code, "the example must not use npga_core"
    imports = set(re.findall(r"^(?:import|from)\s+(\w+)", code, re.M))
    assert imports <= {"json", "numpy"}, f"the example imports {imports}"
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    path = tmp_path / "tiny.npga"
    avatar = read_avatar(path)
    assert len(avatar) == 10 and avatar.cloud.sh_degree == 0 and avatar.cloud.feature_dim == 2
    assert avatar.code_dim == 4 and avatar.dynamics.F is not None and avatar.dynamics.G is None
    assert avatar.cnn is None and avatar.expression.n_components == 2 and list(avatar.expression.named) == ["smile"]
    posed = avatar.pose(avatar.expression.named["smile"])
    assert len(posed) == 10 and np.isfinite(posed.means).all()
    assert np.abs(posed.means - avatar.cloud.means).max() > 0  # F moved the Gaussians


# --------------------------------------------------------------------------------------------------
# the tensor table


@pytest.fixture(scope="module")
def full_header(tmp_path_factory) -> dict:
    path = tmp_path_factory.mktemp("fmt") / "full.npga"
    save_avatar(make_synthetic_avatar(50, latent_dim=4, with_cnn=True), path)
    return read_header(path)[0]


def _table_names() -> set[str]:
    return set(re.findall(r"^\|\s*`([^`]+)`\s*\|", _section(TENSOR_HEADING), re.M))


def test_tensor_table_lists_every_tensor(full_header):
    names = set(expected_tensors(full_header))
    # the full header has every optional tensor kind
    for must in ("gaussians.latent", "gaussians.part_ids", "dynamics.F.layers.0.weight", "dynamics.G.input_scale",
                 "cnn.layers.0.bias", "expression.named"):
        assert must in names
    documented = _table_names()
    missing = sorted({_generic(n) for n in names} - documented)
    assert not missing, f"tensors missing from the table in {DOC.name}: {missing}"


def test_tensor_table_has_no_unknown_names(full_header):
    generic = {_generic(n) for n in expected_tensors(full_header)}
    extra = sorted(_table_names() - generic)
    assert not extra, f"the table in {DOC.name} lists tensors the code does not know: {extra}"


def test_tensor_table_dtypes(full_header):
    rows = re.findall(r"^\|\s*`([^`]+)`\s*\|[^|]*\|\s*(\w+)\s*\|", _section(TENSOR_HEADING), re.M)
    doc_dtype = dict(rows)
    for name, (dtype, _) in expected_tensors(full_header).items():
        assert doc_dtype[_generic(name)] == dtype, name


# --------------------------------------------------------------------------------------------------
# the byte layout and the numpy reference of posing


def _read_by_the_doc(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """Parse a file following section 1 of the document only."""
    raw = path.read_bytes()
    assert raw[:8] == MAGIC
    hlen = int.from_bytes(raw[8:16], "little")
    start = 16 + hlen
    assert start % ALIGN == 0
    header = json.loads(raw[16:start].decode("utf-8"))
    out = {}
    for name, e in header["tensors"].items():
        assert e["offset"] % ALIGN == 0
        dt = {"float32": "<f4", "int16": "<i2"}[e["dtype"]]
        a = np.frombuffer(raw, dtype=dt, count=int(np.prod(e["shape"])), offset=start + e["offset"])
        out[name] = a.reshape(e["shape"]).astype(np.float64) if e["dtype"] == "float32" else a.reshape(e["shape"])
    return header, out


def _avatar(rotation_op: str, activation: str) -> Avatar:
    base = make_synthetic_avatar(40, sh_degree=1, feature_dim=3, latent_dim=2, code_dim=5, hidden=16, depth=4,
                                 n_components=3, parts=False, seed=7)
    gen = torch.Generator().manual_seed(11)
    f_cfg = MLPConfig(3, 5, [("position", 3)], hidden=16, depth=4, activation="silu", pos_freqs=2, skips=[2])
    g_cfg = MLPConfig(3, 5, [("sh", 6), ("rotation", 4), ("opacity", 1), ("scale", 3), ("position", 3),
                             ("latent", 2)], hidden=12, depth=4, activation=activation, pos_freqs=1, skips=[1, 3])
    nets = []
    for cfg in (f_cfg, g_cfg):
        net = ConditionedMLP(cfg)
        with torch.no_grad():
            for p in net.parameters():
                p.copy_(0.5 * torch.randn(p.shape, generator=gen))
            net.input_shift.copy_(0.1 * torch.randn(cfg.raw_input_dim, generator=gen))
            net.input_scale.copy_(0.5 + torch.rand(cfg.raw_input_dim, generator=gen))
            net.layers[-1].weight.mul_(0.1)
        nets.append(net.eval())
    return Avatar(base.cloud, Dynamics(nets[0], nets[1], rotation_op), None, base.expression)


@pytest.mark.parametrize(("rotation_op", "activation"),
                         [("compose", "relu"), ("add", "gelu"), ("compose", "elu"), ("add", "leaky_relu"),
                          ("compose", "softplus"), ("add", "tanh")])
def test_numpy_reference_matches_the_code(tmp_path, rotation_op, activation):
    ns: dict = {}
    exec(compile(_python_block_after(REFERENCE_HEADING), str(DOC), "exec"), ns)
    path = tmp_path / "a.npga"
    save_avatar(_avatar(rotation_op, activation), path)
    avatar = read_avatar(path)
    header, t = _read_by_the_doc(path)
    z = avatar.expression.sample(np.random.default_rng(2), scale=2.0)
    ref = ns["pose"](header, t, z.astype(np.float64))
    got = avatar.pose(z, reference=True)
    tol = {"rtol": 1e-4, "atol": 1e-5}
    np.testing.assert_allclose(ref["means"], got.means, **tol)
    np.testing.assert_allclose(ns["unit"](ref["quats"]), got.quats, **tol)
    np.testing.assert_allclose(np.exp(ref["log_scales"]), got.scales, **tol)
    np.testing.assert_allclose(1 / (1 + np.exp(-ref["opacity_logits"])), got.opacities, **tol)
    np.testing.assert_allclose(ref["sh"], got.sh, **tol)
    np.testing.assert_allclose(ref["latent"], got.latent, **tol)
    # the offsets are not trivially small: posing changed every attribute
    canon = avatar.cloud
    for a, b in ((ref["means"], canon.means), (ref["log_scales"], canon.log_scales), (ref["sh"], canon.sh),
                 (ref["opacity_logits"], canon.opacity_logits), (ref["latent"], canon.latent)):
        assert np.abs(a - b).max() > 1e-3


# --------------------------------------------------------------------------------------------------
# section 16: the blendshape basis (format version 3)

BLENDSHAPES_HEADING = "## 16. Format version 3: a blendshape basis"


def test_blendshape_section_matches_the_code(tmp_path):
    from npga_core.files.checkpoint import FORMAT_VERSION
    from npga_core.model.blendshapes import BlendshapeBasis

    avatar = make_synthetic_avatar(20, code_dim=6, hidden=8, depth=2, n_components=3)
    avatar.blendshapes = BlendshapeBasis(("jawOpen", "eyeBlinkLeft"), np.ones((6, 2)), np.zeros(6), "doc")
    path = tmp_path / "bs.npga"
    save_avatar(avatar, path)
    header = read_header(path)[0]
    assert header["format_version"] == 3 and FORMAT_VERSION == 5
    section = _section(BLENDSHAPES_HEADING)
    rows = dict(re.findall(r"^\|\s*`(blendshapes\.[^`]+)`\s*\|[^|]*\|\s*(\w+)\s*\|", section, re.M))
    implied = {n: dt for n, (dt, _) in expected_tensors(header).items() if n.startswith("blendshapes.")}
    assert rows == implied
    keys = set(re.findall(r"^\|\s*`(\w+)`\s*\|", section.split("### `blendshapes`")[1].split("| name |")[0], re.M))
    assert keys == set(header["blendshapes"])
    assert "currently > 5" in _section("## 8. Validation: what the reader rejects")


RIG_HEADING = "## 17. Format version 4: a linear blendshape rig"


def test_rig_section_matches_the_code(tmp_path):
    """Section 17's keys and tensor table are what `save_avatar` writes for a rig (with stored vertices)."""
    from npga_core.model.linear_rig import LinearRig

    avatar = make_synthetic_avatar(20, code_dim=6, hidden=8, depth=2, n_components=3)
    rig = LinearRig(("jawOpen", "eyeBlinkLeft"), np.array([1, 5]), np.ones((2, 2, 3), np.float32), 20,
                    carrier="vertex", vertices=np.zeros((20, 3), np.float32))
    avatar.dynamics.rig = rig
    avatar.expression = None
    path = tmp_path / "rig.npga"
    save_avatar(avatar, path)
    header = read_header(path)[0]
    assert header["format_version"] == 4
    section = _section(RIG_HEADING)
    rows = dict(re.findall(r"^\|\s*`(rig\.[^`]+)`\s*\|[^|]*\|\s*(\w+)\s*\|", section, re.M))
    implied = {n: dt for n, (dt, _) in expected_tensors(header).items() if n.startswith("rig.")}
    assert rows == implied
    keys = set(re.findall(r"^\|\s*`(\w+)`\s*\|", section.split("### `rig`")[1].split("| name |")[0], re.M))
    assert keys == set(header["rig"])
    back = read_avatar(path)
    z = np.concatenate([np.zeros(6), [0.5, -1.0]]).astype(np.float32)
    assert np.allclose(back.pose(z).means, avatar.pose(z).means, atol=1e-6)
    moved = back.pose(z).means - back.pose(np.zeros(8, np.float32)).means
    assert np.allclose(moved[[1, 5]], -0.5) and np.allclose(np.delete(moved, [1, 5], axis=0), 0.0)
