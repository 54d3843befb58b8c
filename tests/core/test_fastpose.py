"""The exact fast path (`FastPoser`) equals the plain reference forward passes to float tolerance."""

from __future__ import annotations

import copy
import platform

import numpy as np
import pytest
import torch

from npga_core.model.dynamics import ConditionedMLP, Dynamics, MLPConfig
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.posing.fastpose import FastPoser, onednn_available, posed_buffers

FIELDS = ("means", "quats", "scales", "opacities", "sh", "latent")
KERNELS = ["aten", pytest.param("onednn", marks=pytest.mark.skipif(not onednn_available(),
                                                                    reason="torch has no usable oneDNN linear"))]


def _reference_rows(avatar, z: np.ndarray) -> torch.Tensor:
    """Combined offset rows (each attribute's offset summed over the networks, in attribute order) from the plain
    forward passes."""
    totals = avatar.offsets_reference(z).totals()
    return torch.cat(list(totals.values()), dim=1)


def _assert_posed_close(dest: dict, ref, rtol: float = 1e-4, atol: float = 2e-6) -> None:
    for name in FIELDS:
        if dest.get(name) is not None:
            np.testing.assert_allclose(dest[name], getattr(ref, name), rtol=rtol, atol=atol, err_msg=name)


@pytest.mark.slow
@pytest.mark.parametrize("first_layer", ["cache", "recompute"])
@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("kernel", KERNELS)
def test_exact_path_equals_reference_forward(first_layer, threads, kernel):
    a = make_synthetic_avatar(900, latent_dim=3, seed=4)
    poser = FastPoser(a, chunk=256, first_layer=first_layer, threads=threads, kernel=kernel)
    assert (poser.first_layer, poser.kernel) == (first_layer, kernel)
    z = a.expression.sample(np.random.default_rng(1))
    torch.testing.assert_close(poser.offsets(z), _reference_rows(a, z), rtol=1e-4, atol=1e-6)
    dest = posed_buffers(len(a), a.cloud.sh.shape[1], a.cloud.latent_dim)
    assert poser.pose_into(z, dest)
    _assert_posed_close(dest, a.pose(z, reference=True))


@pytest.mark.parametrize("kw", [
    {"sh_degree": 1, "with_f": False},
    {"with_g": False, "feature_dim": 0},
    {"hidden": 32, "depth": 2, "sh_degree": 0},
])
@pytest.mark.parametrize("kernel", KERNELS)
def test_other_layouts_equal_reference(kw, kernel):
    a = make_synthetic_avatar(500, seed=6, **kw)
    poser = FastPoser(a, chunk=128, kernel=kernel)
    z = a.expression.sample(np.random.default_rng(2))
    dest = posed_buffers(len(a), a.cloud.sh.shape[1], a.cloud.latent_dim)
    poser.pose_into(z, dest)
    _assert_posed_close(dest, a.pose(z, reference=True))


def test_other_activation_encoding_and_rotation_op():
    a = make_synthetic_avatar(400, seed=8)
    torch.manual_seed(0)
    old = a.dynamics
    cfg_f = MLPConfig(old.F.config.feature_dim, a.code_dim, [("position", 3)], hidden=24, depth=3,
                      activation="silu", pos_freqs=2)
    cfg_g = MLPConfig(old.G.config.feature_dim, a.code_dim, old.G.config.outputs, hidden=24, depth=3,
                      activation="tanh", pos_freqs=1)
    F, G = ConditionedMLP(cfg_f), ConditionedMLP(cfg_g)
    with torch.no_grad():
        G.layers[-1].weight.mul_(0.05)
    a.dynamics = Dynamics(F.eval(), G.eval(), rotation_op="add")
    a.invalidate_caches()
    z = a.expression.sample(np.random.default_rng(3))
    for mode in ("cache", "recompute"):
        poser = FastPoser(a, chunk=100, first_layer=mode)
        assert poser.kernel == "aten"  # oneDNN is used for ReLU networks only
        dest = posed_buffers(len(a), a.cloud.sh.shape[1], 0)
        poser.pose_into(z, dest)
        _assert_posed_close(dest, a.pose(z, reference=True))


def test_offsets_out_apply_into_and_subsets_agree():
    a = make_synthetic_avatar(700, seed=9)
    poser = FastPoser(a, chunk=200, threads=2)
    z = a.expression.sample(np.random.default_rng(4))
    dest = posed_buffers(len(a), a.cloud.sh.shape[1], 0)
    rows = torch.empty(len(a), poser.layout.width)
    poser.pose_into(z, dest, offsets_out=rows)
    again = posed_buffers(len(a), a.cloud.sh.shape[1], 0)
    poser.apply_into(rows, again, chunk=200)  # same chunk boundaries: bit-equal (SIMD tails round differently)
    for name in dest:
        np.testing.assert_array_equal(dest[name], again[name])
    poser.apply_into(rows, again, chunk=300)
    for name in dest:
        np.testing.assert_allclose(dest[name], again[name], rtol=1e-6, atol=1e-7)
    index = np.array([5, 17, 300, 699])
    sub = poser.offsets(z, rows=poser.subset(index))
    torch.testing.assert_close(sub, rows[index], rtol=1e-5, atol=1e-7)


def test_cancel_stops_between_chunks():
    a = make_synthetic_avatar(600, seed=1)
    poser = FastPoser(a, chunk=100)
    dest = posed_buffers(len(a), a.cloud.sh.shape[1], 0)
    calls = []

    def cancel() -> bool:
        calls.append(1)
        return len(calls) > 2

    assert not poser.pose_into(a.neutral_code(), dest, cancel=cancel)
    assert poser.offsets(a.neutral_code(), cancel=lambda: True) is None


def test_first_layer_cache_is_shared_and_invalidated():
    a = make_synthetic_avatar(300, seed=2)
    poser = FastPoser(a, first_layer="cache")
    assert poser.cache_bytes == 300 * 256 * 4 * 2
    assert all(poser.rows.first[k] is a.first_layer_cache[k] for k in ("F", "G"))
    assert FastPoser(a, first_layer="auto", cache_mb=0.1).first_layer == "recompute"
    v = a.version
    a.invalidate_caches()
    assert a.version == v + 1 and not a.first_layer_cache
    with pytest.raises(RuntimeError, match="edited"):
        poser.offsets(a.neutral_code())


def test_wrong_code_dimension_is_refused():
    a = make_synthetic_avatar(100, seed=3)
    with pytest.raises(ValueError, match="7 dims"):
        FastPoser(a).offsets(np.zeros(7, np.float32))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_path_equals_reference():
    a = make_synthetic_avatar(2000, seed=5)
    poser = FastPoser(a, device="cuda")
    z = a.expression.sample(np.random.default_rng(5))
    dest = posed_buffers(len(a), a.cloud.sh.shape[1], 0)
    poser.pose_into(z, dest)
    _assert_posed_close(dest, a.pose(z, reference=True), rtol=1e-3, atol=1e-5)


@pytest.mark.parametrize("kernel", KERNELS)
def test_relu_chain_with_large_biases_matches_float64(kernel):
    """On torch.mm, ReLU chains carry each hidden layer's bias into the next layer (`_Chain.run`); on oneDNN
    the bias is fused. With biases as large as the activations both equal a float64 forward to float32
    rounding."""
    a = make_synthetic_avatar(600, seed=12)
    with torch.no_grad():
        for net in a.dynamics.networks().values():
            for layer in net.layers[1:]:
                layer.bias.normal_(0.0, 0.5)
    a.invalidate_caches()
    poser = FastPoser(a, chunk=128, threads=2, kernel=kernel)
    chains = poser.chains.values()
    assert all((c.folded is not None, c.packed is not None) == (kernel == "aten", kernel == "onednn")
               for c in chains)
    z = a.expression.sample(np.random.default_rng(5))
    t = a.canonical_tensors()
    got = poser.offsets(z).double()
    mu, f, zz = t["means"].double(), t["features"].double(), torch.from_numpy(z).double()
    ref = torch.cat(list(copy.deepcopy(a.dynamics).double().offsets(mu, f, zz).totals().values()), 1).detach()
    scale = ref.abs().amax(0).clamp_min(1e-12)
    assert float(((got - ref).abs().amax(0) / scale).max()) < 1e-4


def test_kernel_choice():
    """"auto" takes oneDNN on x86-64 CPUs when it is usable; unknown names are refused."""
    a = make_synthetic_avatar(300, seed=9)
    x86 = platform.machine().lower() in ("x86_64", "amd64")
    assert FastPoser(a, chunk=64).kernel == ("onednn" if onednn_available() and x86 else "aten")
    with pytest.raises(ValueError, match="kernel must be one of"):
        FastPoser(a, kernel="fast")
